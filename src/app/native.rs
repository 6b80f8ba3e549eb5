//! The page's core driven natively, as the browser shell drives it: each download read from a
//! weights folder, each request answered by the same CPU [`Runner`] the page's Web Worker runs
//! (there is no WebGPU compute here, so nothing is posted to a GPU). The CLI's `render` draws
//! what a link shows with it.

use std::path::PathBuf;
use std::sync::Arc;

use super::page::{Delivery, Effect, PageCore, PageStart};
use crate::jobs::runner::Runner;
use crate::render::camera::ControlInput;
use crate::render::gpu::FrameParams;
use crate::render::pacing::SceneKey;
use crate::share::{PageOptions, ShareState};
use crate::world::quadtree::NodeData;

/// Page time (milliseconds) each frame of [`NativeShell`] advances.
pub const FRAME_MS: f64 = 16.0;

/// A native stand-in for the browser shell around a [`PageCore`].
pub struct NativeShell {
    runner: Runner,
    weights: PathBuf,
    clock_ms: f64,
}

/// A view whose world has finished streaming, and the frames it took.
pub struct Settled {
    /// The nodes to draw.
    pub nodes: Vec<Arc<NodeData>>,
    /// The frame's parameters.
    pub params: FrameParams,
    /// Frames driven until nothing changed.
    pub frames: usize,
}

impl NativeShell {
    /// A shell answering downloads from `weights` (the page's `weights/` folder) and requests
    /// with a runner whose kernels use `threads` threads.
    pub fn new(weights: PathBuf, threads: usize) -> Self {
        Self { runner: Runner::new(threads), weights, clock_ms: 0.0 }
    }

    /// A page core for the link `fragment` (the part after `#`) and page `query` (after `?`,
    /// e.g. `tem=off`), started as a page with a CPU worker and no WebGPU compute.
    pub fn open(fragment: &str, query: &str) -> Result<PageCore, String> {
        let share = ShareState::from_fragment(fragment).map_err(|e| e.0)?;
        let (options, note) = PageOptions::from_query(query);
        if let Some(note) = note {
            return Err(note);
        }
        let start =
            PageStart { tem: options.tem, world: options.world, gpu: Err("no WebGPU compute natively".into()), software_adapter: false, worker: Ok(()), status: String::new() };
        Ok(PageCore::new(share, start))
    }

    /// Carries out the core's effects, and those their deliveries cause, until none is left.
    pub fn carry_out(&mut self, core: &mut PageCore) {
        loop {
            let effects = core.take_effects();
            if effects.is_empty() {
                return;
            }
            for e in effects {
                match e {
                    Effect::Fetch { id, url } => {
                        let path = self.weights.join(url.trim_start_matches("weights/"));
                        let bytes = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()));
                        core.deliver(Delivery::Fetched { id, bytes });
                    }
                    Effect::Post { envelope, .. } => core.deliver(Delivery::Answer(self.runner.handle(envelope))),
                }
            }
        }
    }

    /// One frame of `size` pixels with no input: the core's frame, its work started and carried
    /// out.
    pub fn frame(&mut self, core: &mut PageCore, size: [u32; 2]) -> (Vec<Arc<NodeData>>, FrameParams) {
        let out = core.app.frame(&ControlInput::default(), FRAME_MS / 1000.0, size);
        core.start_work(self.clock_ms);
        self.clock_ms += FRAME_MS;
        self.carry_out(core);
        out
    }

    /// Frames until the view is whole: no tile, far tile or request pending and the same scene
    /// ([`SceneKey`]: nodes, their versions, the frame's parameters) three frames running; an
    /// error after `max_frames`.
    pub fn settle(&mut self, core: &mut PageCore, size: [u32; 2], max_frames: usize) -> Result<Settled, String> {
        self.carry_out(core);
        let mut same = 0;
        let mut last = None;
        for frames in 1..=max_frames {
            let (nodes, params) = self.frame(core, size);
            let key = Some(SceneKey::of(&nodes, &params));
            let s = core.app.stats();
            let idle = s.tiles_pending == 0 && s.tiles_uncovered == 0 && s.far_pending == 0 && core.in_flight() == 0;
            same = if idle && key == last && !nodes.is_empty() { same + 1 } else { 0 };
            last = key;
            if same >= 3 {
                return Ok(Settled { nodes, params, frames });
            }
        }
        Err(format!("the view was still changing after {max_frames} frames: {:?}", core.app.stats()))
    }
}

/// A picture of what a link shows, drawn natively.
pub struct Still {
    /// Width (pixels).
    pub width: u32,
    /// Height (pixels).
    pub height: u32,
    /// `width × height` RGBA values (sRGB, 8 bits each), rows top to bottom.
    pub rgba: Vec<u8>,
    /// Frames the page's core took until its view was whole.
    pub frames: usize,
    /// Nodes drawn.
    pub nodes: usize,
    /// Milliseconds each draw of the view took on the adapter, submission to completion
    /// (one per repeat).
    pub draw_ms: Vec<f64>,
    /// The adapter drawn on.
    pub adapter: String,
}

/// Draws the view of link `fragment` (page options `query`) at `size` pixels as the page
/// would once its view is whole: the core driven natively ([`NativeShell`], weights from
/// `weights`, kernels on `threads` threads, at most `max_frames` frames), then drawn by the
/// page's renderer on a native (Vulkan) adapter `repeats` times (at least once), each draw
/// timed.
pub fn still(fragment: &str, query: &str, weights: PathBuf, size: [u32; 2], threads: usize, max_frames: usize, repeats: usize) -> Result<Still, String> {
    let settled = settled_view(fragment, query, weights, size, threads, max_frames)?;
    draw_still(&settled, None, repeats)
}

/// The whole view of link `fragment` (page options `query`) at `size` pixels, as [`still`]
/// settles it before drawing.
pub fn settled_view(fragment: &str, query: &str, weights: PathBuf, size: [u32; 2], threads: usize, max_frames: usize) -> Result<Settled, String> {
    let mut core = NativeShell::open(fragment, query)?;
    let mut shell = NativeShell::new(weights, threads);
    let settled = shell.settle(&mut core, size, max_frames)?;
    match &core.message {
        Some(m) => Err(m.clone()),
        None => Ok(settled),
    }
}

/// Draws `settled` on a native (Vulkan) adapter `repeats` times (at least once), each draw
/// timed, with the target encoded as `encoding` says (the adapter's own choice for `None`).
pub fn draw_still(settled: &Settled, encoding: Option<crate::render::TargetEncoding>, repeats: usize) -> Result<Still, String> {
    let gpu = crate::block_on(crate::render::device::open(wgpu::Backends::VULKAN))?;
    let encoding = encoding.unwrap_or_else(|| crate::render::TargetEncoding::for_adapter(&gpu.adapter));
    let mut renderer = crate::render::TerrainRenderer::new(&gpu.device, encoding);
    let mut draw_ms = Vec::new();
    for _ in 0..repeats.max(1) {
        let t = web_time::Instant::now();
        renderer.render(&gpu.device, &gpu.queue, &settled.nodes, &settled.params, super::MESH_KEEP_FRAMES);
        gpu.device.poll(wgpu::PollType::Wait { submission_index: None, timeout: None }).map_err(|e| format!("waiting for the GPU: {e}"))?;
        draw_ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let (width, height, rgba) = renderer.read_target(&gpu.device, &gpu.queue)?;
    Ok(Still { width, height, rgba, frames: settled.frames, nodes: settled.nodes.len(), draw_ms, adapter: gpu.adapter.get_info().name })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A procedural link drawn at 320×200 is a picture of that size whose top row is the sky
    /// (blue over red in every pixel) and whose bottom half is ground in at least 90 % of its
    /// pixels (not the sky's blue-over-red), after the view became whole.
    #[test]
    fn a_procedural_links_still_has_sky_on_top_and_ground_below_at_the_size_asked() {
        let link = "v=2&seed=7&src=procedural&cam=3000,2500,9000,0.9,-0.3&r=2&lod=6&noise=ridged,8,0.5,2,20000,2400,-250&auto=0";
        let s = still(link, "tem=off", crate::repo_root().join("weights"), [320, 200], 1, 2_000, 1).unwrap();
        assert_eq!((s.width, s.height, s.rgba.len()), (320, 200, 320 * 200 * 4));
        assert!(s.nodes > 0 && s.frames >= 3, "{} nodes, {} frames", s.nodes, s.frames);
        let px = |x: usize, y: usize| &s.rgba[(y * 320 + x) * 4..][..3];
        let skyish = |p: &[u8]| p[2] as i32 > p[0] as i32 + 20;
        assert!((0..320).all(|x| skyish(px(x, 0))), "top row {:?}", px(0, 0));
        let ground = (100..200).flat_map(|y| (0..320).map(move |x| (x, y))).filter(|&(x, y)| !skyish(px(x, y))).count();
        assert!(ground as f64 >= 0.9 * 320.0 * 100.0, "{ground} ground pixels of 32000");
    }

    /// The same whole view drawn with the shaders encoding sRGB into a plain target (as on
    /// WebGL2) and with the GPU encoding it into an sRGB target differs by at most 2 levels of
    /// 255 in 99.9 % of the pixel channels and by at most 8 in any (the water is blended in
    /// encoded values with the shaders' encoding), and by under 0.3 levels on average.
    #[test]
    fn the_shaders_srgb_encoding_draws_the_picture_the_gpus_does() {
        use crate::render::TargetEncoding;
        let link = "v=2&seed=7&src=procedural&cam=3000,900,9000,0.9,-0.3&r=2&lod=6&auto=0";
        let settled = settled_view(link, "tem=off", crate::repo_root().join("weights"), [256, 160], 1, 2_000).unwrap();
        let gpu = draw_still(&settled, Some(TargetEncoding::Gpu), 1).unwrap();
        let shader = draw_still(&settled, Some(TargetEncoding::Shader), 1).unwrap();
        assert_eq!(gpu.rgba.len(), shader.rgba.len());
        let diffs: Vec<u8> = gpu.rgba.iter().zip(&shader.rgba).enumerate().filter(|(k, _)| k % 4 != 3).map(|(_, (a, b))| a.abs_diff(*b)).collect();
        let over_2 = diffs.iter().filter(|&&d| d > 2).count();
        let worst = diffs.iter().copied().max().unwrap();
        let mean = diffs.iter().map(|&d| d as f64).sum::<f64>() / diffs.len() as f64;
        println!("{} channels: {over_2} over 2 levels, worst {worst}, mean {mean:.3}", diffs.len());
        assert!((over_2 as f64) <= 0.001 * diffs.len() as f64, "{over_2} channels over 2 levels");
        assert!(worst <= 8, "worst {worst}");
        assert!(mean < 0.3, "mean {mean}");
    }
}
