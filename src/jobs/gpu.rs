//! The requests the GPU answers: TEM batches, sketches and the learned world's network
//! batches on burn's wgpu backend, on the renderer's device in the page (WebGPU) or on Vulkan
//! natively. The same [`Envelope`] and [`Answer`] as the CPU runner, so the core sends work to
//! either the same way; only the readback is asynchronous (browsers require it).

use std::cell::RefCell;
use std::rc::Rc;

use burn::tensor::Device;

use super::protocol::{Answer, Envelope, Reply, Request};
use crate::models::sketch::SketchGenGpu;
use crate::models::tem::{Exec, LEVELS, PROBE_SIDE, TemSet, probe_input};
use crate::models::weights_hash;
use crate::world::learned::{LearnedModels, NetworksOn};

/// The models loaded onto one GPU device.
pub struct GpuRunner {
    device: Device,
    tem: RefCell<Option<Rc<TemSet>>>,
    sketch: RefCell<Option<Rc<SketchGenGpu>>>,
    world: RefCell<Option<Rc<NetworksOn>>>,
}

impl GpuRunner {
    /// A runner on `device` with no models loaded.
    pub fn new(device: Device) -> Self {
        Self { device, tem: RefCell::default(), sketch: RefCell::default(), world: RefCell::default() }
    }

    /// Answers a request: the TEM's, the sketch generator's and the learned world's loads (the
    /// TEM is warmed up on the probe windows, so its kernels compile now and not in the middle
    /// of a flight), TEM batches, sketches and batches of the world's network work. Other
    /// requests are CPU work: an error reply says so.
    pub async fn handle(&self, env: Envelope) -> Answer {
        let t0 = web_time::Instant::now();
        let ms = || t0.elapsed().as_secs_f64() * 1e3;
        let reply = match env.request {
            Request::LoadTem { files } => {
                let hash = weights_hash(&files.iter().map(Vec::as_slice).collect::<Vec<_>>());
                match self.load_tem(files).await {
                    Ok(()) => Reply::Loaded { hash },
                    Err(e) => Reply::Failed(e),
                }
            }
            Request::LoadSketch { generator, vae } => match SketchGenGpu::from_burnpack(&generator, &self.device) {
                Ok(g) => {
                    *self.sketch.borrow_mut() = Some(Rc::new(g));
                    Reply::Loaded { hash: weights_hash(&[&generator, &vae]) }
                }
                Err(e) => Reply::Failed(e.to_string()),
            },
            Request::LoadWorld { tcm, grow } => {
                match LearnedModels::from_bytes(&tcm, &grow).map_err(|e| e.to_string()).and_then(|m| Ok((NetworksOn::new(&m, &self.device)?, m.hash))) {
                    Ok((networks, hash)) => {
                        *self.world.borrow_mut() = Some(Rc::new(networks));
                        Reply::Loaded { hash }
                    }
                    Err(e) => Reply::Failed(e),
                }
            }
            Request::RunWork { work, halves } => {
                let world = self.world.borrow().clone();
                match (world, work.check()) {
                    (Some(networks), Ok(())) => match networks.run(&work, halves).await {
                        Ok(outputs) => Reply::Outputs { outputs, ms: ms() },
                        Err(e) => Reply::Failed(e),
                    },
                    (None, _) => Reply::Failed("the GPU has no learned world loaded".into()),
                    (_, Err(e)) => Reply::Failed(e),
                }
            }
            Request::Enhance { level, n, side, input } => {
                let tem = self.tem.borrow().clone();
                match tem {
                    Some(tem) if (level as usize) < LEVELS => match tem.enhance_async(level as usize, input, n as usize, side as usize).await {
                        Ok(heights) => Reply::Heights { heights, ms: ms() },
                        Err(e) => Reply::Failed(e),
                    },
                    Some(_) => Reply::Failed(format!("no TEM level {level}")),
                    None => Reply::Failed("the GPU has no TEM loaded".into()),
                }
            }
            Request::Sketch { sketch, extent_m } => {
                let generator = self.sketch.borrow().clone();
                match (generator, sketch.sketch()) {
                    (Some(g), Ok(s)) => match g.generate_async(&s, extent_m).await {
                        Ok(heights) => Reply::Heights { heights, ms: ms() },
                        Err(e) => Reply::Failed(e),
                    },
                    (None, _) => Reply::Failed("the GPU has no sketch generator loaded".into()),
                    (_, Err(e)) => Reply::Failed(format!("the request's sketch is broken ({e})")),
                }
            }
            other => Reply::Failed(format!("the GPU does not run {} requests", other.kind())),
        };
        Answer { id: env.id, reply }
    }

    async fn load_tem(&self, files: Vec<Vec<u8>>) -> Result<(), String> {
        let tem = TemSet::from_bytes(files, &Exec::Burn(self.device.clone())).map_err(|e| e.to_string())?;
        for k in 0..LEVELS {
            tem.enhance_async(k, probe_input(k), 1, PROBE_SIDE).await?;
        }
        *self.tem.borrow_mut() = Some(Rc::new(tem));
        Ok(())
    }
}
