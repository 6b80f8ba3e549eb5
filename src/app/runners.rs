//! Who runs the core's requests: the CPU worker behind a [`Port`] (a Web Worker in the page,
//! a [`crate::jobs::native::NativeRunner`] thread natively), burn on the GPU, and a runner on
//! the calling thread for when there is no worker. The shell hands each [`Effect::Post`] to
//! [`Runners::call`] and delivers what comes back; the page, the CLI's tests and the native
//! tests dispatch the same way.
//!
//! [`Effect::Post`]: super::page::Effect::Post

use std::cell::RefCell;
use std::rc::Rc;

use super::page::{Delivery, Target, next_id};
use crate::jobs::gpu::GpuRunner;
use crate::jobs::protocol::{Answer, Envelope, Reply, Request};
use crate::jobs::runner::Runner;
use crate::models::tem::{LEVELS, PROBE_SIDE, ProbeTimes, probe_input, probe_json};

/// The way to a CPU worker on another thread.
pub trait Port {
    /// Posts `env` and waits for its answer; `Err(why)` when the worker is gone.
    fn call(&self, env: &Envelope) -> impl Future<Output = Result<Answer, String>>;
    /// Why the worker is gone, if it is.
    fn gone(&self) -> Option<String>;
}

#[cfg(not(target_arch = "wasm32"))]
impl Port for crate::jobs::native::NativeRunner {
    async fn call(&self, env: &Envelope) -> Result<Answer, String> {
        crate::jobs::native::NativeRunner::call(self, env).map_err(|e| e.to_string())
    }

    fn gone(&self) -> Option<String> {
        None
    }
}

/// The page's runners.
pub struct Runners<W> {
    /// The CPU worker, if the platform gave one.
    pub worker: Option<Rc<W>>,
    /// burn on the GPU, if its self-check passed.
    pub gpu: Option<Rc<GpuRunner>>,
    /// The CPU kernels on this thread.
    pub main: RefCell<Runner>,
}

impl<W: Port> Runners<W> {
    /// Runners with a worker (or none), the GPU (or none) and one kernel thread here.
    pub fn new(worker: Option<Rc<W>>, gpu: Option<GpuRunner>) -> Self {
        Self { worker, gpu: gpu.map(Rc::new), main: RefCell::new(Runner::new(1)) }
    }

    /// Runs `env` on `target` and returns what the core is to be told: the answer, or that
    /// the worker is gone (the core then fails what it held and falls back).
    pub async fn call(&self, target: Target, env: Envelope) -> Delivery {
        let id = env.id;
        match target {
            Target::Worker => match &self.worker {
                Some(w) => match w.call(&env).await {
                    Ok(a) => Delivery::Answer(a),
                    Err(why) => Delivery::WorkerGone { id, why },
                },
                None => Delivery::WorkerGone { id, why: "there is no CPU worker".into() },
            },
            Target::Gpu => match &self.gpu {
                Some(g) => Delivery::Answer(g.handle(env).await),
                None => Delivery::Answer(Answer { id, reply: Reply::Failed("burn cannot use the GPU".into()) }),
            },
            Target::MainThread => Delivery::Answer(self.main.borrow_mut().handle(env)),
        }
    }

    /// Runs the fixed TEM probe (one window per level) on `target`, for world `epoch` (so the
    /// worker does not take it for an older world's): JSON `{backend, levels, round_trip_ms,
    /// compute_ms}` ([`probe_json`]; the compute time is the worker's own clock, where it runs).
    pub async fn tem_probe(&self, target: Target, backend: &str, epoch: u64) -> Result<String, String> {
        let (mut levels, mut compute_ms) = (Vec::new(), 0.0);
        let t0 = web_time::Instant::now();
        for k in 0..LEVELS {
            let request = Request::Enhance { level: k as u8, n: 1, side: PROBE_SIDE as u32, input: probe_input(k) };
            match self.call(target, Envelope { id: next_id(), epoch, rest_per_work: 0.0, request }).await {
                Delivery::Answer(Answer { reply: Reply::Heights { heights, ms }, .. }) => {
                    compute_ms += ms;
                    levels.push(heights);
                }
                other => return Err(format!("the probe of level {k} failed: {other:?}")),
            }
        }
        let round_trip_ms = Some(t0.elapsed().as_secs_f64() * 1e3);
        Ok(probe_json(backend, &levels, ProbeTimes { round_trip_ms, compute_ms: (target == Target::Worker).then_some(compute_ms) }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::block_on;
    use crate::grid::TileCoord;
    use crate::jobs::native::NativeRunner;

    fn heights(d: Delivery) -> Vec<f32> {
        match d {
            Delivery::Answer(Answer { reply: Reply::Heights { heights, .. }, .. }) => heights,
            other => panic!("{other:?}"),
        }
    }

    /// The worker thread and the main thread answer the same requests alike (a loaded TEM's
    /// probe: the same heights on both, and the worker's compute time reported); the GPU
    /// target without a GPU answers that burn cannot use it; without a worker, a worker
    /// request is delivered as a gone worker.
    #[test]
    fn requests_go_the_same_way_to_the_worker_thread_and_the_main_thread() {
        let runners = Runners::new(Some(Rc::new(NativeRunner::spawn(1))), None);
        let files: Vec<Vec<u8>> = (0..LEVELS).map(|k| std::fs::read(crate::repo_root().join("weights").join(crate::models::tem::weight_file(k))).unwrap()).collect();
        for target in [Target::Worker, Target::MainThread] {
            let d = block_on(runners.call(target, Envelope { id: next_id(), epoch: 0, rest_per_work: 0.0, request: Request::LoadTem { files: files.clone() } }));
            assert!(matches!(d, Delivery::Answer(Answer { reply: Reply::Loaded { .. }, .. })), "{d:?}");
        }
        let worker: serde_json::Value = serde_json::from_str(&block_on(runners.tem_probe(Target::Worker, "CPU", 3)).unwrap()).unwrap();
        let main: serde_json::Value = serde_json::from_str(&block_on(runners.tem_probe(Target::MainThread, "CPU", 3)).unwrap()).unwrap();
        assert_eq!(worker["levels"], main["levels"]);
        assert!(worker["compute_ms"].as_f64().unwrap() > 0.0 && main["compute_ms"].is_null());
        let tile = || Envelope { id: next_id(), epoch: 3, rest_per_work: 0.0, request: Request::Tile { seed: 2, tile: TileCoord::new(0, 1), noise: Some(Default::default()) } };
        assert_eq!(heights(block_on(runners.call(Target::Worker, tile()))), heights(block_on(runners.call(Target::MainThread, tile()))));
        let d = block_on(runners.call(Target::Gpu, tile()));
        assert!(matches!(&d, Delivery::Answer(Answer { reply: Reply::Failed(w), .. }) if w == "burn cannot use the GPU"), "{d:?}");
        let alone: Runners<NativeRunner> = Runners::new(None, None);
        assert!(matches!(block_on(alone.call(Target::Worker, tile())), Delivery::WorkerGone { .. }));
    }

    /// A learned world's tile made by the CPU worker (a thread here) with its network work run
    /// by the GPU runner (burn on wgpu: lavapipe here), message by message as the page passes
    /// them (world-work, run-work, accept-work until none is left, then the tile; the ×4
    /// step's batches run in halves with a wait for the device between them), is the tile the
    /// CPU makes alone, bit for bit, after at most 5 batches; a batch of the wrong size is
    /// refused by the GPU and by the worker, and outputs that do not fit their batch by the
    /// worker, saying so.
    #[test]
    fn a_world_tile_with_its_networks_on_the_gpu_runner_is_the_cpu_tile_bit_for_bit() {
        use crate::world::learned::{GROW_FILE, NetworkWork, TCM_FILE};
        let dir = crate::repo_root().join("weights");
        let (tcm, grow) = (std::fs::read(dir.join(TCM_FILE)).unwrap(), std::fs::read(dir.join(GROW_FILE)).unwrap());
        let gpu = GpuRunner::new(crate::models::native_gpu().expect("a Vulkan device (lavapipe)"));
        let runners = Runners::new(Some(Rc::new(NativeRunner::spawn(1))), Some(gpu));
        let call = |target: Target, request: Request| match block_on(runners.call(target, Envelope { id: next_id(), epoch: 0, rest_per_work: 0.0, request })) {
            Delivery::Answer(a) => a.reply,
            other => panic!("{other:?}"),
        };
        for target in [Target::Worker, Target::Gpu, Target::MainThread] {
            let r = call(target, Request::LoadWorld { tcm: tcm.clone(), grow: grow.clone() });
            assert!(matches!(r, Reply::Loaded { .. }), "{target:?}: {r:?}");
        }
        let (seed, tile) = (5, TileCoord::new(1, 0));
        let mut batches = Vec::new();
        loop {
            let work = match call(Target::Worker, Request::WorldWork { seed, tile, coarse: false }) {
                Reply::Work(w) => w,
                other => panic!("{other:?}"),
            };
            if work == NetworkWork::None {
                break;
            }
            let halves = matches!(work, NetworkWork::Grow(_));
            let (outputs, ms) = match call(Target::Gpu, Request::RunWork { work: work.clone(), halves }) {
                Reply::Outputs { outputs, ms } => (outputs, ms),
                other => panic!("{other:?}"),
            };
            batches.push(work.len());
            assert_eq!(call(Target::Worker, Request::AcceptWork { seed, keys: work.keys(), outputs, ms }), Reply::Accepted);
            assert!(batches.len() <= 5, "batches {batches:?}");
        }
        let tile_of = |target| match call(target, Request::Tile { seed, tile, noise: None }) {
            Reply::Heights { heights, .. } => heights,
            other => panic!("{other:?}"),
        };
        let (made, alone) = (tile_of(Target::Worker), tile_of(Target::MainThread));
        let differ = made.iter().zip(&alone).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
        assert!(batches.len() >= 2 && differ == 0, "{differ} of {} samples differ; batches {batches:?}", made.len());
        let broken = NetworkWork::Tcm(vec![(tile, vec![0.0; 10])]);
        for target in [Target::Gpu, Target::Worker] {
            let r = call(target, Request::RunWork { work: broken.clone(), halves: false });
            assert!(matches!(&r, Reply::Failed(w) if w.contains("not the networks' sizes")), "{target:?}: {r:?}");
        }
        let r = call(Target::Worker, Request::AcceptWork { seed, keys: broken.keys(), outputs: Vec::new(), ms: 1.0 });
        assert!(matches!(&r, Reply::Failed(w) if w.contains("0 outputs for 1 tiles")), "{r:?}");
    }
}
