//! What the page exports to JavaScript for its end-to-end test and the browser console: the
//! latest statistics, frame intervals, a tile's heights, the TEM probe, memory and the
//! static-constructor count. A user never needs them.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::atomic::AtomicU32;
use std::sync::atomic::Ordering::SeqCst;

use wasm_bindgen::prelude::*;

use super::Runners;
use crate::grid::TileCoord;
use crate::jobs::runner::Runner;
use crate::models::tem::LEVELS;
use crate::ui::shell::Probes;

/// What the page's shell publishes for the hooks, and its runners (for the TEM probe).
pub(super) type Published = (Rc<RefCell<Probes>>, Rc<Runners>);

thread_local! {
    pub(super) static PROBES: RefCell<Option<Published>> = const { RefCell::new(None) };
}

/// `f` of the shell's probes (`None` before the page runs).
fn probes<T>(f: impl FnOnce(&mut Probes) -> T) -> Option<T> {
    PROBES.with(|p| p.borrow().as_ref().map(|(p, _)| f(&mut p.borrow_mut())))
}

/// The intervals (milliseconds) between the frames of the 3-D view drawn since the previous
/// call, oldest first: the frame times a person sees.
#[wasm_bindgen]
pub fn terrain_frame_intervals() -> Vec<f64> {
    probes(|p| std::mem::take(&mut p.frame_intervals)).unwrap_or_default()
}

/// The latest frame statistics as JSON.
#[wasm_bindgen]
pub fn terrain_stats() -> String {
    probes(|p| p.stats_json.clone()).filter(|s| !s.is_empty()).unwrap_or_else(|| "{}".into())
}

/// Stops (`true`) or resumes drawing frames: the test times CPU inference without the
/// software rasteriser drawing on the same cores.
#[wasm_bindgen]
pub fn terrain_set_paused(paused: bool) {
    probes(|p| p.set_paused(paused));
}

/// Asks for the heights of tile (i, j) of the world shown (see [`terrain_tile_heights`]).
#[wasm_bindgen]
pub fn terrain_request_tile(i: i32, j: i32) {
    probes(|p| p.tile = (Some(TileCoord::new(i, j)), None));
}

/// The heights (JSON array, metres) of the tile asked for, or `null` while the world does not
/// have it yet.
#[wasm_bindgen]
pub fn terrain_tile_heights() -> String {
    probes(|p| serde_json::to_string(&p.tile.1).unwrap_or_default()).unwrap_or_else(|| "null".into())
}

/// Bytes of the page's wasm linear memory now (it only grows).
#[wasm_bindgen]
pub fn terrain_wasm_memory_bytes() -> f64 {
    (core::arch::wasm32::memory_size(0) * 65_536) as f64
}

/// Runs the fixed TEM probe on the page's TEM (wherever it runs) and returns JSON
/// `{backend, levels, round_trip_ms, compute_ms}` ([`crate::app::runners::Runners::tem_probe`]).
#[wasm_bindgen]
pub async fn terrain_tem_probe() -> Result<String, JsValue> {
    let runners = PROBES.with(|p| p.borrow().as_ref().map(|(_, r)| r.clone())).ok_or("the page is not running")?;
    let (target, backend, epoch) = probes(|p| p.tem.clone()).flatten().ok_or("the TEM is not loaded")?;
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
