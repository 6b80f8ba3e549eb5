//! What the page exports to JavaScript for its end-to-end test and the browser console: the
//! latest statistics, frame intervals, a tile's heights, the TEM probe, memory and the
//! static-constructor count. A user never needs them.

use std::cell::{Cell, RefCell};
use std::rc::Rc;
use std::sync::atomic::AtomicU32;
use std::sync::atomic::Ordering::SeqCst;

use wasm_bindgen::prelude::*;

use super::Runners;
use crate::app::page::Target;
use crate::grid::TileCoord;
use crate::jobs::runner::Runner;
use crate::models::tem::{LEVELS, probe_input};

/// Most frame intervals kept for [`terrain_frame_intervals`] (over half an hour at 60 fps).
const MAX_FRAME_INTERVALS: usize = 120_000;

/// Where the TEM runs now, for the probe: the runners, the target, its name, the world epoch.
pub(super) struct TemProbe {
    pub runners: Rc<Runners>,
    pub target: Target,
    pub backend: String,
    pub epoch: u64,
}

thread_local! {
    pub(super) static STATS_JSON: RefCell<String> = RefCell::new("{}".into());
    pub(super) static TEM_PROBE: RefCell<Option<TemProbe>> = const { RefCell::new(None) };
    /// The tile asked for ([`terrain_request_tile`]) and its heights once the world has it.
    pub(super) static TILE_PROBE: RefCell<(Option<TileCoord>, Option<Vec<f32>>)> = const { RefCell::new((None, None)) };
    static FRAME_INTERVALS: RefCell<Vec<f64>> = const { RefCell::new(Vec::new()) };
    /// Frames are not drawn while set ([`terrain_set_paused`]), and the context to wake.
    pub(super) static PAUSED: Cell<bool> = const { Cell::new(false) };
    pub(super) static CONTEXT: RefCell<Option<egui::Context>> = const { RefCell::new(None) };
}

/// Keeps one frame interval (ms) for [`terrain_frame_intervals`].
pub(super) fn record_frame_interval(ms: f64) {
    FRAME_INTERVALS.with(|f| {
        let mut f = f.borrow_mut();
        if f.len() < MAX_FRAME_INTERVALS {
            f.push(ms);
        }
    });
}

/// The intervals (milliseconds) between the frames of the 3-D view drawn since the previous
/// call, oldest first: the frame times a person sees.
#[wasm_bindgen]
pub fn terrain_frame_intervals() -> Vec<f64> {
    FRAME_INTERVALS.with(|f| std::mem::take(&mut *f.borrow_mut()))
}

/// The latest frame statistics as JSON.
#[wasm_bindgen]
pub fn terrain_stats() -> String {
    STATS_JSON.with(|s| s.borrow().clone())
}

/// Stops (`true`) or resumes drawing frames: the test times CPU inference without the
/// software rasteriser drawing on the same cores.
#[wasm_bindgen]
pub fn terrain_set_paused(paused: bool) {
    PAUSED.set(paused);
    if !paused {
        CONTEXT.with(|c| c.borrow().as_ref().map(|ctx| ctx.request_repaint()));
    }
}

/// Asks for the heights of tile (i, j) of the world shown (see [`terrain_tile_heights`]).
#[wasm_bindgen]
pub fn terrain_request_tile(i: i32, j: i32) {
    TILE_PROBE.with(|p| *p.borrow_mut() = (Some(TileCoord::new(i, j)), None));
}

/// The heights (JSON array, metres) of the tile asked for, or `null` while the world does not
/// have it yet.
#[wasm_bindgen]
pub fn terrain_tile_heights() -> String {
    TILE_PROBE.with(|p| serde_json::to_string(&p.borrow().1).unwrap_or_default())
}

/// Bytes of the page's wasm linear memory now (it only grows).
#[wasm_bindgen]
pub fn terrain_wasm_memory_bytes() -> f64 {
    (core::arch::wasm32::memory_size(0) * 65_536) as f64
}

/// The TEM probe's input window of level `level` (JSON array of heights).
#[wasm_bindgen]
pub fn terrain_probe_input(level: usize) -> String {
    serde_json::to_string(&probe_input(level.min(LEVELS - 1))).unwrap_or_default()
}

/// Runs the fixed TEM probe on the page's TEM (wherever it runs) and returns JSON
/// `{backend, levels, round_trip_ms, compute_ms}` ([`Runners::tem_probe`]).
///
/// [`Runners::tem_probe`]: crate::app::runners::Runners::tem_probe
#[wasm_bindgen]
pub async fn terrain_tem_probe() -> Result<String, JsValue> {
    let probe = TEM_PROBE.with(|t| t.borrow().as_ref().map(|p| (p.runners.clone(), p.target, p.backend.clone(), p.epoch)));
    let (runners, target, backend, epoch) = probe.ok_or("the TEM is not loaded")?;
    Ok(runners.tem_probe(target, &backend, epoch).await?)
}

/// The TEM's CPU kernels on the page's main thread ([`Runner::time_tem`], level 0, `reps`
/// runs): JSON `{ms: [per run], out: [last heights]}`.
#[wasm_bindgen]
pub async fn terrain_main_thread_tem(reps: u32) -> Result<String, JsValue> {
    let mut files = Vec::new();
    for k in 0..LEVELS {
        files.push(super::files::fetch(&format!("weights/{}", crate::models::tem::weight_file(k))).await?);
    }
    let (ms, out) = Runner::new(1).time_tem(files, reps as usize)?;
    Ok(serde_json::json!({ "ms": ms, "out": out }).to_string())
}

/// How many times this module's static constructors have run.
static CONSTRUCTOR_RUNS: AtomicU32 = AtomicU32::new(0);

/// A static constructor of our own, beside burn's: it counts its runs.
#[used]
#[unsafe(link_section = ".init_array")]
static COUNT_CONSTRUCTOR_RUNS: extern "C" fn() = {
    extern "C" fn count() {
        CONSTRUCTOR_RUNS.fetch_add(1, SeqCst);
    }
    count
};

/// How many times the module's static constructors have run: 1 however often JavaScript has
/// called into the module.
#[wasm_bindgen]
pub fn terrain_constructor_runs() -> u32 {
    CONSTRUCTOR_RUNS.load(SeqCst)
}

/// Panics on the main thread, as a bug would (the end-to-end test shows the page then says it
/// stopped and offers a reload with the view kept).
#[wasm_bindgen]
pub fn terrain_test_panic() {
    panic!("a panic asked for by terrain_test_panic");
}
