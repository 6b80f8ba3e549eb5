//! The browser shell: checks for WebGPU, creates the one wgpu device that rendering and burn
//! share, reads the share link, and runs the app inside eframe. Everything it calls is
//! testable natively; this file only glues browser events to it.

mod worker;

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::atomic::AtomicU32;
use std::sync::atomic::Ordering::SeqCst;

use wasm_bindgen::JsCast;
use wasm_bindgen::prelude::*;

use crate::app::{LearnedStatus, MESH_KEEP_FRAMES, REFINE_BATCH, TerrainApp};
use crate::jobs::Job;
use crate::world::{SourceKind, TileCoord};
use crate::world::learned::{GROW_FILE, TCM_FILE};
use crate::models;
use crate::models::tem::{Exec, LEVELS, PROBE_SIDE, ProbeTimes, TemSet, probe_input, probe_json, weight_file};
use crate::world::PatchKey;
use crate::world::refine::INPUT_SIDE;
use crate::render::camera::ControlInput;
use crate::render::gpu::TerrainRenderer;
use crate::models::runtime::{self, Backend, CpuReason};
use crate::models::runtime::TemChoice;
use crate::share::{PageOptions, ShareState};
use crate::sketch::Sketch;
use crate::ui::sketch::SketchPanel;
use crate::ui::{Environment, Overlay};

const NO_WEBGPU: &str = "This page needs WebGPU, which this browser does not offer. Try a current Chrome, Edge or Safari (or enable WebGPU in the browser's settings).";

thread_local! {
    static STATS_JSON: RefCell<String> = RefCell::new("{}".into());
    static TEM: RefCell<Option<(Rc<TemEngine>, String)>> = const { RefCell::new(None) };
    /// Frames are not drawn while set (see [`terrain_set_paused`]), and the context to wake.
    static PAUSED: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
    static CONTEXT: RefCell<Option<egui::Context>> = const { RefCell::new(None) };
    /// The running eframe runner and the GPU device it draws with (replaced after a loss).
    static RUNNER: RefCell<Option<eframe::WebRunner>> = const { RefCell::new(None) };
    static DEVICE: RefCell<Option<wgpu::Device>> = const { RefCell::new(None) };
    /// The CPU inference worker (kept across device restarts), or why there is none.
    static WORKER: RefCell<Option<Result<Rc<worker::CpuWorker>, String>>> = const { RefCell::new(None) };
    /// The tile the end-to-end test asked for ([`terrain_request_tile`]) and its heights once
    /// the world has it.
    static TILE_PROBE: RefCell<(Option<TileCoord>, Option<Vec<f32>>)> = const { RefCell::new((None, None)) };
    /// Intervals (ms) between the 3-D view's frames since [`terrain_frame_intervals`] was last
    /// called (at most [`MAX_FRAME_INTERVALS`]).
    static FRAME_INTERVALS: RefCell<Vec<f64>> = const { RefCell::new(Vec::new()) };
    /// How many times the page replaced a lost GPU device.
    static RESTARTS: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

/// The generation of the page's current GPU device (1 for the first, +1 per replacement).
static DEVICE_GEN: AtomicU32 = AtomicU32::new(0);
/// The generation of a device that was lost (by the browser, or by [`terrain_lose_device`]);
/// when it is the current one, the next frame stops drawing and the page starts again on a
/// new device, keeping the view. A late notice about an older device changes nothing.
static LOST_DEVICE: AtomicU32 = AtomicU32::new(0);

/// Destroys the page's GPU device, as a driver reset or a browser would take it away (the
/// end-to-end test uses it to show the page recovers); `false` if there is none.
#[wasm_bindgen]
pub fn terrain_lose_device() -> bool {
    DEVICE.with(|d| match d.borrow().as_ref() {
        Some(device) => {
            LOST_DEVICE.store(DEVICE_GEN.load(SeqCst), SeqCst);
            device.destroy();
            true
        }
        None => false,
    })
}

/// Replaces the lost device: stops the old renderer and starts the page again on a new
/// device (or without WebGPU compute, on the CPU) at view `state`.
async fn restart(state: ShareState, why: String) {
    RUNNER.with(|r| r.borrow_mut().take()).inspect(|r| r.destroy());
    RESTARTS.set(RESTARTS.get() + 1);
    let note = format!("The GPU device was lost ({why}); the page started a new one and kept the view.");
    if let Err(e) = run(Some((state, note))).await {
        show_page_message(&format!("The GPU device was lost and a new one could not be started: {e}"));
    }
}

/// Stops (`true`) or resumes drawing frames. The end-to-end test times the CPU inference
/// without the software rasteriser drawing on the same cores; a user never needs it.
#[wasm_bindgen]
pub fn terrain_set_paused(paused: bool) {
    PAUSED.set(paused);
    if !paused {
        CONTEXT.with(|c| c.borrow().as_ref().map(|ctx| ctx.request_repaint()));
    }
}

/// Where the page's TEM runs.
enum TemEngine {
    /// burn on the shared WebGPU device.
    Gpu(TemSet),
    /// The CPU kernels in a Web Worker (the main thread only posts and receives).
    Worker(Rc<worker::CpuWorker>),
    /// The CPU kernels on the main thread, when the browser could not start the worker: it
    /// blocks frames, so quads are rationed.
    MainThread(TemSet),
}

impl TemEngine {
    /// Runs level `level` on `n` windows of side `side` (see [`TemSet::enhance_async`]);
    /// returns the heights and, where the backend measures it (the CPU worker, on its own
    /// clock), its compute time in milliseconds.
    /// The worker rests `rest_per_work` ms per ms of work between windows
    /// ([`worker::CpuWorker::enhance`]).
    async fn enhance(&self, level: usize, inputs: Vec<f32>, n: usize, side: usize, rest_per_work: f64) -> Result<(Vec<f32>, Option<f64>), String> {
        match self {
            TemEngine::Gpu(tem) | TemEngine::MainThread(tem) => tem.enhance_async(level, inputs, n, side).await.map(|out| (out, None)),
            TemEngine::Worker(w) => w.enhance(level, inputs, n, side, rest_per_work).await.map(|(out, ms)| (out, Some(ms))).map_err(|e| e.to_string()),
        }
    }
}

/// State of the learned refinement shared between the frame loop and the async tasks that
/// load the weights and run inference.
#[derive(Default)]
struct Ml {
    /// The self-check / backend line of the overlay.
    status: String,
    /// The loaded models and where they run ("WebGPU" or "CPU").
    tem: Option<(Rc<TemEngine>, String)>,
    /// Weight files loaded so far (of `LEVELS`), while loading.
    loading: Option<usize>,
    /// Why the TEM is off, if it failed.
    error: Option<String>,
    /// A batch is running.
    busy: bool,
    /// Finished batches: world epoch, keys, raw output or error, milliseconds.
    results: Vec<(u64, Vec<PatchKey>, Result<Vec<f32>, String>, f64)>,
    /// The learned world's models once their loading ended: the weights hash, or why they
    /// are not available.
    world: Option<Result<String, String>>,
    /// Finished learned tiles: the job, and the heights and the worker's milliseconds or the
    /// error.
    tiles: Vec<(Job<TileCoord>, Result<(Vec<f32>, f64), String>)>,
    /// The sketch models: not asked for yet (`None`), loading, loaded (their hash)
    /// or why they are not available.
    sketch: Option<Option<Result<String, String>>>,
    /// Finished sketch → terrain jobs.
    sketches: Vec<(Job<u64>, Result<(Vec<f32>, f64), String>)>,
    /// Proposed variants (or why they failed), once they come back.
    variants: Option<Result<Vec<(Sketch, Vec<f32>)>, String>>,
    /// A blend came back (or failed).
    blend: Option<Result<(Sketch, Vec<f32>), String>>,
    /// Variants or a blend are being made.
    sketch_busy: bool,
    /// Blends that came back and were drawn.
    blends: u32,
    /// The shared GPU device when the models run on it (a hardware adapter, or `?tem=gpu`).
    gpu: Option<burn::tensor::Device>,
    /// The sketch generator on that device (strokes are made there; variants and blends, and
    /// strokes without it, in the CPU worker).
    sketch_gpu: Option<Rc<crate::models::sketch::SketchGenGpu>>,
}

/// Loads the sketch models (generator and VAE, fetched at once) into the CPU worker, and the
/// generator onto the GPU when the models run there, and records their hash, or why they are
/// not available, in `ml`. A generator that fails on the GPU leaves the strokes to the worker.
async fn start_sketch(worker: Result<Rc<worker::CpuWorker>, String>, ml: Rc<RefCell<Ml>>) {
    let files = [crate::models::sketch::WEIGHT_FILE, crate::models::sketch_vae::WEIGHT_FILE];
    let gpu = ml.borrow().gpu.clone();
    let on_gpu = Rc::new(RefCell::new(None));
    let slot = on_gpu.clone();
    let result = load_pair(files, worker, |w, a, b| async move {
        if let Some(device) = gpu {
            *slot.borrow_mut() = Some(crate::models::sketch::SketchGenGpu::from_burnpack(&a, &device));
        }
        w.load_sketch(&a, &b).await
    })
    .await;
    let mut ml = ml.borrow_mut();
    match on_gpu.take() {
        Some(Ok(g)) if result.is_ok() => ml.sketch_gpu = Some(Rc::new(g)),
        Some(Err(e)) => web_sys::console::warn_1(&format!("the sketch generator could not run on the GPU ({e}); strokes go to the CPU worker").into()),
        _ => {}
    }
    ml.sketch = Some(Some(result));
}

/// The page's CPU inference worker, started once (and kept when a lost device restarts the
/// page), or why the browser could not start it.
async fn cpu_worker() -> Result<Rc<worker::CpuWorker>, String> {
    if let Some(w) = WORKER.with(|w| w.borrow().clone())
        && w.as_ref().map_or(true, |w| w.gone().is_none())
    {
        return w;
    }
    let w = worker::CpuWorker::start().await.map(Rc::new).map_err(|e| e.to_string());
    WORKER.with(|slot| *slot.borrow_mut() = Some(w.clone()));
    w
}

/// Loads the learned world's weights (both requests go out at once) into the CPU worker and
/// records the hash, or why the learned world is not available, in `ml`.
async fn start_world(worker: Result<Rc<worker::CpuWorker>, String>, ml: Rc<RefCell<Ml>>) {
    let result = load_pair([TCM_FILE, GROW_FILE], worker, |w, a, b| async move { w.load_world(&a, &b).await }).await;
    ml.borrow_mut().world = Some(result);
}

/// Fetches two weight files (both requests go out at once) and hands them to the CPU worker
/// with `load`; returns its answer (a weights hash) or why the models are not available.
async fn load_pair<F, Fut>(files: [&str; 2], worker: Result<Rc<worker::CpuWorker>, String>, load: F) -> Result<String, String>
where
    F: FnOnce(Rc<worker::CpuWorker>, Vec<u8>, Vec<u8>) -> Fut,
    Fut: std::future::Future<Output = Result<String, worker::WorkerError>>,
{
    let urls = files.map(|f| format!("weights/{f}"));
    let requests: Vec<_> = urls.iter().map(|u| start_fetch(u)).collect();
    let mut bytes = Vec::new();
    for (url, request) in urls.iter().zip(requests) {
        bytes.push(fetched_bytes(url, request?).await.map_err(|e| format!("its weights could not be loaded ({e})"))?);
    }
    let w = worker.map_err(|e| format!("it needs a Web Worker ({e})"))?;
    let (b, a) = (bytes.pop().unwrap_or_default(), bytes.pop().unwrap_or_default());
    load(w, a, b).await.map_err(|e| match e {
        worker::WorkerError::Failed(e) => format!("its weights are broken ({e})"),
        worker::WorkerError::Unavailable(e) => format!("the CPU worker stopped ({e})"),
    })
}

/// Runs the fixed TEM probe on the page's models (whichever backend they run on) and returns
/// JSON `{backend, levels: [[every height…] per level], round_trip_ms, compute_ms}` (see [`probe_json`]) for the
/// end-to-end test.
#[wasm_bindgen]
pub async fn terrain_tem_probe() -> Result<String, JsValue> {
    let Some((tem, backend)) = TEM.with(|t| t.borrow().clone()) else {
        return Err("the TEM is not loaded".into());
    };
    let mut levels = Vec::new();
    let mut compute_ms = None;
    let t0 = web_time::Instant::now();
    for k in 0..LEVELS {
        let (raw, ms) = tem.enhance(k, probe_input(k), 1, PROBE_SIDE, 0.0).await.map_err(|e| JsValue::from_str(&e))?;
        // The worker's own clock too: the kernels' time without the round trip.
        if let Some(ms) = ms {
            compute_ms = Some(compute_ms.unwrap_or(0.0) + ms);
        }
        levels.push(raw);
    }
    let round_trip_ms = Some(t0.elapsed().as_secs_f64() * 1e3);
    Ok(probe_json(&backend, &levels, ProbeTimes { round_trip_ms, compute_ms }))
}

/// The TEM probe's input window of level `level` (JSON array of heights), so the end-to-end
/// test can run the kernels on exactly the probe's data.
#[wasm_bindgen]
pub fn terrain_probe_input(level: usize) -> String {
    serde_json::to_string(&probe_input(level.min(LEVELS - 1))).unwrap_or_default()
}

/// Asks the page for the heights of tile (i, j) of the world shown (see
/// [`terrain_tile_heights`]); the end-to-end test compares them with the native CLI's.
#[wasm_bindgen]
pub fn terrain_request_tile(i: i32, j: i32) {
    TILE_PROBE.with(|p| *p.borrow_mut() = (Some(TileCoord::new(i, j)), None));
}

/// The heights (JSON array, metres) of the tile asked for with [`terrain_request_tile`], or
/// `null` while the world does not have it yet.
#[wasm_bindgen]
pub fn terrain_tile_heights() -> String {
    TILE_PROBE.with(|p| serde_json::to_string(&p.borrow().1).unwrap_or_default())
}

/// Bytes of the page's wasm linear memory now (it only grows; the end-to-end test samples it
/// during a long flight to show it stops growing).
#[wasm_bindgen]
pub fn terrain_wasm_memory_bytes() -> f64 {
    (core::arch::wasm32::memory_size(0) * 65_536) as f64
}

/// Starts fetching `url`: the request is in flight when this returns, so several can
/// download at once.
fn start_fetch(url: &str) -> Result<wasm_bindgen_futures::JsFuture, String> {
    let window = web_sys::window().ok_or("no window")?;
    Ok(wasm_bindgen_futures::JsFuture::from(window.fetch_with_str(url)))
}

/// The body of a fetch started by [`start_fetch`].
async fn fetched_bytes(url: &str, request: wasm_bindgen_futures::JsFuture) -> Result<Vec<u8>, String> {
    use wasm_bindgen_futures::JsFuture;
    let resp: web_sys::Response = request.await.map_err(|e| format!("{url}: {e:?}"))?.dyn_into().map_err(|_| format!("{url}: not a response"))?;
    if !resp.ok() {
        return Err(format!("{url}: HTTP {}", resp.status()));
    }
    let buf = JsFuture::from(resp.array_buffer().map_err(|e| format!("{url}: {e:?}"))?).await.map_err(|e| format!("{url}: {e:?}"))?;
    Ok(js_sys::Uint8Array::new(&buf).to_vec())
}

/// The page's options from its query string (`?tem=…`) and a notice for values it did not
/// understand.
fn page_options() -> (PageOptions, Option<String>) {
    PageOptions::from_query(&web_sys::window().and_then(|w| w.location().search().ok()).unwrap_or_default())
}

/// Starts burn: self-check on the shared GPU device, then loads the TEM weights onto it, or
/// onto the CPU kernels when the GPU path is unavailable or fails (and says so).
async fn start_ml(gpu: Result<burn::tensor::Device, String>, software: bool, choice: TemChoice, worker: Result<Rc<worker::CpuWorker>, String>, ml: Rc<RefCell<Ml>>) {
    let t0 = now_ms();
    let gpu = match gpu {
        Ok(device) => match models::self_check(&device).await {
            Ok(err) if err < 1e-3 => {
                ml.borrow_mut().status = format!("burn wgpu ready (self-check {:.0} ms, max |Δ| {err:.1e} m)", now_ms() - t0);
                Ok(device)
            }
            Ok(err) => Err(format!("burn wgpu gives wrong results (max |Δ| {err} m)")),
            Err(e) => Err(format!("burn wgpu failed: {e}")),
        },
        Err(e) => Err(e),
    };
    let chosen = runtime::choose(choice, gpu.as_ref().map(|_| ()).map_err(Clone::clone), software);
    if let (Ok(device), true) = (&gpu, chosen.is_gpu()) {
        ml.borrow_mut().gpu = Some(device.clone());
    }
    if let Backend::Cpu(CpuReason::NoGpuCompute(e)) = &chosen {
        ml.borrow_mut().status = format!("{e}; the TEM runs on the CPU");
    }
    let mut backend = chosen.label();
    ml.borrow_mut().loading = Some(0);
    let mut files = Vec::new();
    // All five requests go out at once; their bodies are read in level order.
    let urls: Vec<String> = (0..LEVELS).map(|k| format!("weights/{}", weight_file(k))).collect();
    let requests: Vec<_> = urls.iter().map(|u| start_fetch(u)).collect();
    for (k, (url, request)) in urls.iter().zip(requests).enumerate() {
        match async { fetched_bytes(url, request?).await }.await {
            Ok(b) => files.push(b),
            Err(e) => {
                let mut m = ml.borrow_mut();
                m.loading = None;
                m.error = Some(format!("TEM weights could not be loaded ({e}); showing the 32 m world"));
                return;
            }
        }
        ml.borrow_mut().loading = Some(k + 1);
        set_loading_note(&format!("Loading the learned detail models {}/{LEVELS}…", k + 1));
    }
    ml.borrow_mut().loading = None;
    let broken = |e: &dyn std::fmt::Display| format!("TEM weights are broken ({e}); showing the 32 m world");
    let tem = match gpu {
        Ok(d) if chosen.is_gpu() => TemSet::from_bytes(files, &Exec::Burn(d)).map(TemEngine::Gpu).map_err(|e| broken(&e)),
        _ => match worker {
            Ok(w) => match w.load_tem(&files).await {
                Ok(()) => Ok(TemEngine::Worker(w)),
                // Broken weights fail alike on any thread: no second try on the main thread.
                Err(worker::WorkerError::Failed(e)) => Err(broken(&e)),
                Err(worker::WorkerError::Unavailable(e)) => Err(format!("the CPU worker stopped ({e}); showing the 32 m world")),
            },
            Err(e) => {
                web_sys::console::warn_1(&format!("CPU worker unavailable ({e}); the TEM runs on the main thread").into());
                backend = format!("{backend} on the main thread");
                TemSet::from_bytes(files, &Exec::cpu()).map(TemEngine::MainThread).map_err(|e| broken(&e))
            }
        },
    };
    let tem = match tem {
        Ok(tem) => Rc::new(tem),
        Err(e) => {
            ml.borrow_mut().error = Some(e);
            return;
        }
    };
    set_loading_note("Preparing the learned detail models…");
    let t0 = now_ms();
    for k in 0..if chosen.is_gpu() { LEVELS } else { 0 } {
        if let Err(e) = tem.enhance(k, probe_input(k), 1, PROBE_SIDE, 0.0).await {
            ml.borrow_mut().error = Some(format!("TEM failed on {backend} ({e}); showing the 32 m world"));
            return;
        }
    }
    web_sys::console::log_1(&format!("TEM warm-up on {backend}: {:.0} ms", now_ms() - t0).into());
    TEM.with(|t| *t.borrow_mut() = Some((tem.clone(), backend.clone())));
    ml.borrow_mut().tem = Some((tem, backend));
}

/// The browser's own description of its WebGPU adapter ("vendor architecture") and whether
/// it is a software (CPU-emulated) adapter such as SwiftShader, read from `adapter.info`.
async fn browser_adapter_info() -> Option<(String, bool)> {
    use js_sys::Reflect;
    let nav = web_sys::window()?.navigator();
    let gpu = Reflect::get(&nav, &"gpu".into()).ok()?;
    let request = Reflect::get(&gpu, &"requestAdapter".into()).ok()?.dyn_into::<js_sys::Function>().ok()?;
    let promise = request.call0(&gpu).ok()?.dyn_into::<js_sys::Promise>().ok()?;
    let adapter = wasm_bindgen_futures::JsFuture::from(promise).await.ok()?;
    let info = Reflect::get(&adapter, &"info".into()).ok()?;
    let field = |k: &str| Reflect::get(&info, &k.into()).ok().and_then(|v| v.as_string()).unwrap_or_default();
    let (vendor, arch, desc) = (field("vendor"), field("architecture"), field("description"));
    let fallback = Reflect::get(&info, &"isFallbackAdapter".into()).ok().and_then(|v| v.as_bool()).unwrap_or(false);
    let text = [vendor, arch, desc].into_iter().filter(|s| !s.is_empty()).collect::<Vec<_>>().join(" ");
    let software = fallback || text.to_ascii_lowercase().contains("swiftshader") || text.to_ascii_lowercase().contains("llvmpipe");
    Some((text, software))
}

/// Asks for one more frame. egui answers `request_repaint()` with two (to let frame-delayed
/// responses settle); the second would draw the overlay again while the GPU works on the
/// paced 3-D view. A non-zero delay asks for exactly one, at the next animation frame.
fn repaint_once(ctx: &egui::Context) {
    ctx.request_repaint_after(std::time::Duration::from_micros(1));
}

/// Replaces the text of the page's loading note (shown until the renderer starts).
fn set_loading_note(text: &str) {
    if let Some(el) = web_sys::window().and_then(|w| w.document()).and_then(|d| d.query_selector("#loading p").ok().flatten()) {
        el.set_text_content(Some(text));
    }
}

/// Most frame intervals kept for [`terrain_frame_intervals`] (over half an hour at 60 fps).
const MAX_FRAME_INTERVALS: usize = 120_000;

/// The intervals (milliseconds) between the frames of the 3-D view drawn since the previous
/// call, oldest first: the frame times a person sees (the end-to-end test reads them).
#[wasm_bindgen]
pub fn terrain_frame_intervals() -> Vec<f64> {
    FRAME_INTERVALS.with(|f| std::mem::take(&mut *f.borrow_mut()))
}

/// The latest frame statistics as JSON (read by the end-to-end test and usable from the
/// browser console).
#[wasm_bindgen]
pub fn terrain_stats() -> String {
    STATS_JSON.with(|s| s.borrow().clone())
}

/// How many times this module's static constructors have run (see [`terrain_constructor_runs`]).
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
/// called into the module (the end-to-end test checks it after a flight).
#[wasm_bindgen]
pub fn terrain_constructor_runs() -> u32 {
    CONSTRUCTOR_RUNS.load(SeqCst)
}

unsafe extern "C" {
    /// The module's static constructors (the `inventory` registrations of burn's GPU
    /// compiler), synthesised by the linker.
    fn __wasm_call_ctors();
}

/// Page (and CPU worker) entry point: the first call into the module after it is
/// instantiated.
#[wasm_bindgen(start)]
pub fn start() {
    // The static constructors run once, here. Without this explicit call the linker wraps
    // every export in a call to them (a "command" module): every call from JavaScript into
    // the module, down to each JS value handed over, ran them all again — over a third of
    // the page's main-thread time.
    // SAFETY: called once, first thing after instantiation, before any code that reads what
    // the constructors register.
    unsafe { __wasm_call_ctors() };
    console_error_panic_hook::set_once();
    // The same module also runs in the CPU inference worker, which has no page to start.
    if web_sys::window().is_none() {
        return;
    }
    wasm_bindgen_futures::spawn_local(async {
        if let Err(e) = run(None).await {
            show_page_message(&e);
        }
    });
}

/// Shows `text` in the page's message box (outside the canvas, so it works without WebGPU).
fn show_page_message(text: &str) {
    web_sys::console::warn_1(&text.into());
    let Some(doc) = web_sys::window().and_then(|w| w.document()) else { return };
    if let Some(el) = doc.get_element_by_id("message") {
        el.set_text_content(Some(text));
        let _ = el.set_attribute("style", "display:block");
    }
    if let Some(el) = doc.get_element_by_id("loading") {
        let _ = el.set_attribute("style", "display:none");
    }
}

fn now_ms() -> f64 {
    web_sys::window().and_then(|w| w.performance()).map(|p| p.now()).unwrap_or(0.0)
}

fn location_hash() -> String {
    web_sys::window().and_then(|w| w.location().hash().ok()).unwrap_or_default()
}

/// Starts the page: the view from the link, or `restart` (the view to keep and a note) after
/// a lost device.
async fn run(restart: Option<(ShareState, String)>) -> Result<(), String> {
    let window = web_sys::window().ok_or("no window")?;
    let document = window.document().ok_or("no document")?;
    let canvas: web_sys::HtmlCanvasElement = document
        .get_element_by_id("terrain_canvas")
        .ok_or("the page has no #terrain_canvas")?
        .dyn_into()
        .map_err(|_| "#terrain_canvas is not a canvas")?;
    let gpu = js_sys::Reflect::get(&window.navigator(), &"gpu".into()).unwrap_or(JsValue::UNDEFINED);
    if gpu.is_undefined() || gpu.is_null() {
        return Err(NO_WEBGPU.into());
    }
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::BROWSER_WEBGPU;
    let instance = wgpu::Instance::new(desc);
    let adapter = instance
        .request_adapter(&wgpu::RequestAdapterOptions { power_preference: wgpu::PowerPreference::HighPerformance, ..Default::default() })
        .await
        .map_err(|e| format!("{NO_WEBGPU} ({e})"))?;
    let (device, queue) = adapter
        .request_device(&wgpu::DeviceDescriptor {
            label: Some("terrain"),
            required_features: adapter.features().difference(wgpu::Features::MAPPABLE_PRIMARY_BUFFERS),
            required_limits: adapter.limits(),
            ..Default::default()
        })
        .await
        .map_err(|e| format!("Could not open the GPU device: {e}"))?;
    let generation = DEVICE_GEN.fetch_add(1, SeqCst) + 1;
    device.set_device_lost_callback(move |_, _| LOST_DEVICE.store(generation, SeqCst));
    DEVICE.with(|d| *d.borrow_mut() = Some(device.clone()));
    let info = adapter.get_info();
    let label = [&info.name, &info.driver, &info.driver_info].into_iter().find(|s| !s.is_empty()).cloned().unwrap_or_else(|| "browser adapter".into());
    let browser_info = browser_adapter_info().await;
    let software = browser_info.as_ref().is_some_and(|i| i.1);
    let adapter_name = match &browser_info {
        Some((text, _)) if !text.is_empty() => format!("WebGPU · {text}"),
        _ => format!("WebGPU · {label}"),
    };

    let ml = Rc::new(RefCell::new(Ml { status: "starting burn on the GPU…".into(), ..Default::default() }));
    let gpu = models::device_from_setup(models::WgpuSetup { instance: instance.clone(), adapter: adapter.clone(), device: device.clone(), queue: queue.clone(), backend: wgpu::Backend::BrowserWebGpu });
    // Load and warm up the TEM before the renderer starts: its GPU kernels are compiled while
    // the page shows its loading note, not in the middle of a flight (17 s on SwiftShader).
    let (page_opts, options_notice) = page_options();
    let worker = cpu_worker().await;
    wasm_bindgen_futures::spawn_local(start_world(worker.clone(), ml.clone()));
    start_ml(gpu, software, page_opts.tem, worker, ml.clone()).await;

    let hash = location_hash();
    let (share, message) = match (restart, ShareState::from_fragment(&hash)) {
        (Some((state, note)), _) => (state, Some(note)),
        (None, Ok(s)) if s.link_version == 1 => (s, Some("This link is from an older version of the page (version 1): it opens the procedural world it was made with, which may differ from what its sender saw.".into())),
        (None, Ok(s)) => (s, options_notice),
        (None, Err(e)) => (ShareState::default(), Some(format!("{e}. Showing the default world instead."))),
    };

    let options = eframe::WebOptions {
        wgpu_options: eframe::egui_wgpu::WgpuConfiguration {
            wgpu_setup: eframe::egui_wgpu::WgpuSetup::Existing(eframe::egui_wgpu::WgpuSetupExisting { instance, adapter, device, queue }),
            ..Default::default()
        },
        ..Default::default()
    };
    let runner = eframe::WebRunner::new();
    runner
        .start(
            canvas,
            options,
            Box::new(move |cc| {
                let rs = cc.wgpu_render_state.as_ref().ok_or("eframe started without wgpu")?;
                let renderer = TerrainRenderer::new(&rs.device);
                Ok(Box::new(WebApp {
                    app: TerrainApp::new(share.clone()),
                    overlay: Overlay::new(share),
                    renderer,
                    texture: None,
                    env: Environment { adapter: adapter_name, software_adapter: software, ..Default::default() },
                    ml,
                    refine_on: page_opts.tem != TemChoice::Off,
                    last_eye: None,
                    last_cpu_quad_ms: 0.0,
                    message,
                    last_frame_ms: None,
                    pacer: Default::default(),
                    gpu_done: Default::default(),
                    complete_epoch: None,
                    frame_work: Default::default(),
                    last_hash: hash,
                    last_url_write_ms: 0.0,
                    copied_at_ms: None,
                    link_too_long: 0,
                    sketch_panel: SketchPanel::default(),
                    examples: crate::sketch::examples::all(),
                    import: Rc::default(),
                    pending_blend: None,
                }))
            }),
        )
        .await
        .map_err(|e| format!("The page could not start its renderer: {e:?}"))?;
    RUNNER.with(|r| *r.borrow_mut() = Some(runner));
    if let Some(el) = document.get_element_by_id("loading") {
        let _ = el.set_attribute("style", "display:none");
    }
    Ok(())
}

struct WebApp {
    app: TerrainApp,
    overlay: Overlay,
    renderer: TerrainRenderer,
    texture: Option<egui::TextureId>,
    env: Environment,
    ml: Rc<RefCell<Ml>>,
    refine_on: bool,
    last_eye: Option<(glam::DVec3, f64)>,
    last_cpu_quad_ms: f64,
    message: Option<String>,
    last_frame_ms: Option<f64>,
    /// Draws a frame of the 3-D view only once the GPU has finished the previous one.
    pacer: crate::render::FramePacer,
    /// The newest frame whose GPU work is done (set by the queue's callback).
    gpu_done: std::sync::Arc<std::sync::atomic::AtomicU64>,
    /// The world epoch whose view was last complete (no tile pending).
    complete_epoch: Option<u64>,
    /// The main thread's work per frame over the last 120 frames: total, tiles, nodes and
    /// drawing milliseconds, the upload and submit parts of the drawing (ms), and the meshes
    /// uploaded.
    frame_work: std::collections::VecDeque<[f64; 7]>,
    last_hash: String,
    last_url_write_ms: f64,
    copied_at_ms: Option<f64>,
    /// Times "Copy link" found the sketch too detailed for a link and sent it as a file.
    link_too_long: u32,
    sketch_panel: SketchPanel,
    examples: Vec<(&'static str, Sketch)>,
    /// A sketch PNG the user opened (or why it could not be read), once it is read.
    import: Rc<RefCell<Option<Result<Sketch, String>>>>,
    /// A blend α asked for while another blend was being made (the latest wins).
    pending_blend: Option<f32>,
}

/// Offers `sketch` as `sketch.png` in the format's palette.
fn download_sketch(sketch: &crate::sketch::Sketch) -> Result<(), String> {
    let mut png = Vec::new();
    sketch.write_png(&mut png).map_err(|e| e.to_string())?;
    download("sketch.png", &png, "image/png")
}

/// Offers `bytes` as a file download named `name`.
fn download(name: &str, bytes: &[u8], mime: &str) -> Result<(), String> {
    let err = |e: JsValue| format!("{e:?}");
    let parts = js_sys::Array::of1(&js_sys::Uint8Array::from(bytes));
    let props = web_sys::BlobPropertyBag::new();
    props.set_type(mime);
    let blob = web_sys::Blob::new_with_u8_array_sequence_and_options(&parts, &props).map_err(err)?;
    let url = web_sys::Url::create_object_url_with_blob(&blob).map_err(err)?;
    let document = web_sys::window().and_then(|w| w.document()).ok_or("no document")?;
    let a: web_sys::HtmlAnchorElement = document.create_element("a").map_err(err)?.dyn_into().map_err(|_| "no anchor element")?;
    a.set_href(&url);
    a.set_download(name);
    a.click();
    // The download reads the blob after this returns: revoking the URL now can cancel it.
    let revoke = Closure::once_into_js(move || {
        let _ = web_sys::Url::revoke_object_url(&url);
    });
    web_sys::window().ok_or("no window")?.set_timeout_with_callback_and_timeout_and_arguments_0(revoke.unchecked_ref(), 60_000).map_err(err)?;
    Ok(())
}

/// Asks the user for a sketch PNG; the sketch (or why it is not one) lands in `slot`.
fn pick_sketch_file(slot: Rc<RefCell<Option<Result<Sketch, String>>>>) -> Result<(), String> {
    let err = |e: JsValue| format!("{e:?}");
    let document = web_sys::window().and_then(|w| w.document()).ok_or("no document")?;
    let input: web_sys::HtmlInputElement = document.create_element("input").map_err(err)?.dyn_into().map_err(|_| "no input element")?;
    input.set_type("file");
    input.set_accept("image/png");
    input.set_id("terrain_sketch_file");
    let _ = input.set_attribute("style", "display:none");
    document.body().ok_or("no body")?.append_child(&input).map_err(err)?;
    let el = input.clone();
    let on_change = Closure::<dyn FnMut()>::new(move || {
        let Some(file) = el.files().and_then(|f| f.get(0)) else { return };
        let (slot, el) = (slot.clone(), el.clone());
        wasm_bindgen_futures::spawn_local(async move {
            let read = wasm_bindgen_futures::JsFuture::from(file.array_buffer()).await;
            let result = match read {
                Ok(buf) => Sketch::read_png(std::io::Cursor::new(js_sys::Uint8Array::new(&buf).to_vec())).map_err(|e| format!("{}: {e}", file.name())),
                Err(e) => Err(format!("{} could not be read: {e:?}", file.name())),
            };
            *slot.borrow_mut() = Some(result);
            el.remove();
        });
    });
    input.set_onchange(Some(on_change.as_ref().unchecked_ref()));
    on_change.forget();
    input.click();
    Ok(())
}

impl WebApp {
    /// Loads the sketch models once the sketch world is shown, hands finished terrains,
    /// variants and blends to the app and the panel, and starts the next sketch job.
    fn pump_sketch(&mut self, ctx: &egui::Context) {
        if self.app.source() != crate::world::SourceKind::Sketch {
            return;
        }
        let Some(Ok(w)) = WORKER.with(|w| w.borrow().clone()) else {
            if !matches!(self.app.sketch_models(), LearnedStatus::Failed(_)) {
                self.app.set_sketch_models(LearnedStatus::Failed("no CPU worker".into()));
                self.message = Some("The sketch generator needs a Web Worker: showing the band interpolation instead.".into());
            }
            return;
        };
        let mut ml = self.ml.borrow_mut();
        match ml.sketch.clone() {
            None => {
                ml.sketch = Some(None);
                wasm_bindgen_futures::spawn_local(start_sketch(Ok(w.clone()), self.ml.clone()));
            }
            Some(Some(Ok(hash))) if !matches!(self.app.sketch_models(), LearnedStatus::Ready { .. }) => self.app.set_sketch_models(LearnedStatus::Ready { hash }),
            Some(Some(Err(why))) if !matches!(self.app.sketch_models(), LearnedStatus::Failed(_)) => {
                self.app.set_sketch_models(LearnedStatus::Failed(why.clone()));
                self.message = Some(format!("The sketch generator is not available: {why}. Showing the band interpolation instead."));
            }
            _ => {}
        }
        for (job, result) in std::mem::take(&mut ml.sketches) {
            match result {
                Ok((h, ms)) => {
                    self.app.sketch_done(&job, h, ms);
                }
                Err(e) => {
                    self.app.sketch_failed(&job);
                    self.message = Some(format!("The sketch could not be made into terrain: {e}"));
                }
            }
        }
        match ml.variants.take() {
            Some(Ok(v)) => self.sketch_panel.set_variants(ctx, v),
            Some(Err(e)) => self.message = Some(format!("No variants: {e}")),
            None => {}
        }
        match ml.blend.take() {
            Some(Ok((s, _))) => {
                ml.blends += 1;
                self.app.canvas.load(s);
            }
            Some(Err(e)) => self.message = Some(format!("No blend: {e}")),
            None => {}
        }
        if !ml.sketch_busy
            && let Some(alpha) = self.pending_blend.take()
            && let Some((a, b)) = self.sketch_panel.blend_pair()
        {
            ml.sketch_busy = true;
            let (w, shared, a, b) = (w.clone(), self.ml.clone(), a.clone(), b.clone());
            wasm_bindgen_futures::spawn_local(async move {
                let r = w.blend(&a, &b, alpha).await.map_err(|e| e.to_string());
                let mut ml = shared.borrow_mut();
                ml.blend = Some(r);
                ml.sketch_busy = false;
            });
        }
        drop(ml);
        self.start_sketch_jobs(&w);
    }

    /// Sends the canvas's newest sketch to the generator (the GPU, else the CPU worker) if it
    /// has no terrain yet and none is being made. Runs at the start of a frame and again right
    /// after the sketch panel, so a stroke goes out in the frame that drew it.
    fn start_sketch_jobs(&mut self, w: &Rc<worker::CpuWorker>) {
        let on_gpu = self.ml.borrow().sketch_gpu.clone();
        for (job, sketch) in self.app.sketch_jobs() {
            let (w, shared, on_gpu) = (w.clone(), self.ml.clone(), on_gpu.clone());
            wasm_bindgen_futures::spawn_local(async move {
                let t0 = now_ms();
                let on_gpu = match on_gpu {
                    Some(g) => Some(g.generate_async(&sketch).await),
                    None => None,
                };
                let out = match on_gpu {
                    Some(Ok(h)) => Ok((h, now_ms() - t0)),
                    gpu_failed => {
                        if let Some(Err(e)) = gpu_failed {
                            // The GPU failed: this stroke and the next ones go to the worker.
                            web_sys::console::warn_1(&format!("the sketch generator failed on the GPU ({e}); strokes go to the CPU worker").into());
                            shared.borrow_mut().sketch_gpu = None;
                        }
                        w.sketch(&sketch).await.map_err(|e| e.to_string())
                    }
                };
                shared.borrow_mut().sketches.push((job, out));
            });
        }
    }

    /// The sketch panel's requests: files, variants, blends, relief.
    fn sketch_actions(&mut self, act: crate::ui::sketch::SketchActions) {
        if act.export {
            if let Err(e) = download_sketch(self.app.canvas.sketch()) {
                self.message = Some(format!("The sketch could not be exported: {e}"));
            }
        }
        if act.import
            && let Err(e) = pick_sketch_file(self.import.clone())
        {
            self.message = Some(format!("No file dialog: {e}"));
        }
        match self.import.borrow_mut().take() {
            Some(Ok(s)) => self.app.canvas.load(s),
            Some(Err(e)) => self.message = Some(e),
            None => {}
        }
        if act.variants {
            let ready = matches!(self.app.sketch_models(), LearnedStatus::Ready { .. });
            if let (true, Some(Ok(w))) = (ready, WORKER.with(|w| w.borrow().clone())) {
                self.ml.borrow_mut().sketch_busy = true;
                let (shared, sketch) = (self.ml.clone(), self.app.canvas.sketch().clone());
                let seed = self.app.stats().sketch_revision;
                wasm_bindgen_futures::spawn_local(async move {
                    let r = w.variants(&sketch, 4, seed).await.map_err(|e| e.to_string());
                    let mut ml = shared.borrow_mut();
                    ml.variants = Some(r);
                    ml.sketch_busy = false;
                });
            } else {
                self.message = Some("Variants need the sketch models, which are not ready.".into());
            }
        }
        if let Some(a) = act.blend {
            self.pending_blend = Some(a);
        }
        if let Some(r) = act.relief_m {
            let mut s = self.app.share_state();
            s.relief_m = r;
            self.app.apply_settings(s.clone());
            self.overlay.reset(s);
        }
    }
    /// How long the CPU worker rests per ms of work ([`runtime::worker_rest_per_work`]); the
    /// view is complete once the world of this epoch had no tile pending.
    fn worker_rest_per_work(&mut self) -> f64 {
        if self.app.stats().tiles_pending == 0 {
            self.complete_epoch = Some(self.app.epoch());
        }
        self.env.worker_rest_per_work = runtime::worker_rest_per_work(self.env.software_adapter, self.complete_epoch == Some(self.app.epoch()));
        self.env.worker_rest_per_work
    }

    /// Tells the app when the learned world's models are ready or failed, hands it finished
    /// tiles, and starts the tile jobs it asks for in the CPU worker.
    fn pump_world(&mut self) {
        let rest = self.worker_rest_per_work();
        let mut ml = self.ml.borrow_mut();
        match (ml.world.clone(), self.app.learned().clone()) {
            (Some(Ok(hash)), LearnedStatus::Loading) => {
                if let Some(note) = self.app.set_learned(LearnedStatus::Ready { hash }) {
                    self.message = Some(note);
                }
            }
            (Some(Err(why)), LearnedStatus::Loading | LearnedStatus::Ready { .. }) => {
                self.app.set_learned(LearnedStatus::Failed(why.clone()));
                self.message = Some(format!("The learned world is not available: {why}. Showing the procedural world."));
            }
            _ => {}
        }
        for (job, result) in std::mem::take(&mut ml.tiles) {
            match result {
                Ok((heights, ms)) => {
                    self.app.tile_done(&job, heights, ms);
                }
                Err(e) => {
                    self.app.tile_failed(&job);
                    ml.world = Some(Err(format!("making tile {}, {} failed ({e})", job.key.i, job.key.j)));
                }
            }
        }
        let Some(Ok(w)) = WORKER.with(|w| w.borrow().clone()) else { return };
        if let Some(why) = w.gone() {
            if matches!(self.app.learned(), LearnedStatus::Ready { .. }) {
                ml.world = Some(Err(format!("the CPU worker stopped ({why})")));
            }
            // Procedural tiles are made on this thread again.
            self.app.set_procedural_elsewhere(false);
            return;
        }
        self.app.set_procedural_elsewhere(true);
        let seed = self.app.settings().seed;
        let noise = (self.app.source() == SourceKind::Procedural).then(|| self.app.settings().noise);
        for job in self.app.tile_jobs() {
            let (w, shared) = (w.clone(), self.ml.clone());
            wasm_bindgen_futures::spawn_local(async move {
                let out = w.tile(seed, job.key, noise, rest).await.map_err(|e| e.to_string());
                shared.borrow_mut().tiles.push((job, out));
            });
        }
    }

    /// Hands finished TEM batches to the app, turns refinement on once the models are ready,
    /// and starts the next batch (one at a time, so frames keep their budget).
    fn pump_refinement(&mut self) {
        let mut ml = self.ml.borrow_mut();
        for (epoch, keys, out, ms) in ml.results.drain(..) {
            match out {
                Ok(raw) => self.app.refine_done(epoch, &keys, &raw, ms),
                Err(e) => {
                    self.app.refine_failed(epoch, &keys);
                    self.message = Some(format!("TEM inference failed: {e}"));
                }
            }
        }
        let Some((tem, backend)) = ml.tem.clone() else { return };
        if let TemEngine::Worker(w) = &*tem
            && let Some(why) = w.gone()
        {
            ml.tem = None;
            ml.error = Some(format!("The CPU worker stopped ({why}); showing the 32 m world"));
            TEM.with(|t| *t.borrow_mut() = None);
            self.app.set_refinement(None);
            return;
        }
        let want = self.refine_on.then(|| backend.clone());
        if self.app.stats().refine_backend != want.clone().unwrap_or_default() {
            self.app.set_refinement(want);
        }
        if ml.busy || !self.refine_on {
            return;
        }
        // On the main thread the CPU path blocks the page while it runs (tens of ms a quad in
        // wasm): one quad at a time, at most one a second, and only while the camera is slow
        // (< 60 m/s), so flights stay smooth and detail fills in where the user looks. The GPU
        // and the worker take whole batches.
        let now = now_ms();
        let eye = self.app.camera.position_m;
        let speed = self.last_eye.map_or(0.0, |(p, t)| (eye - p).length() / ((now - t) / 1000.0).max(1e-3));
        self.last_eye = Some((eye, now));
        let blocking = matches!(*tem, TemEngine::MainThread(_));
        if blocking && (now - self.last_cpu_quad_ms < 1000.0 || speed > 60.0) {
            return;
        }
        let max = if blocking { 1 } else { REFINE_BATCH };
        let jobs = self.app.refine_jobs(max);
        if jobs.is_empty() {
            return;
        }
        ml.busy = true;
        drop(ml);
        if blocking {
            self.last_cpu_quad_ms = now;
        }
        let shared = self.ml.clone();
        let rest = self.worker_rest_per_work();
        wasm_bindgen_futures::spawn_local(async move {
            let keys: Vec<PatchKey> = jobs.iter().map(|j| j.key).collect();
            let (level, epoch) = (keys[0].level as usize, jobs[0].epoch);
            let t0 = now_ms();
            let out = tem.enhance(level, jobs.into_iter().flat_map(|j| j.input).collect(), keys.len(), INPUT_SIDE, rest).await;
            // The worker's own milliseconds of work (without its rests), else the wall time.
            let ms = out.as_ref().ok().and_then(|(_, ms)| *ms).unwrap_or(now_ms() - t0);
            let out = out.map(|(out, _)| out);
            let mut m = shared.borrow_mut();
            m.results.push((epoch, keys, out, ms));
            m.busy = false;
        });
    }

    /// A link opened in this same page (the fragment changed under us).
    fn follow_hash(&mut self) {
        let hash = location_hash();
        if hash == self.last_hash {
            return;
        }
        self.last_hash = hash.clone();
        match ShareState::from_fragment(&hash) {
            Ok(s) => {
                self.overlay.reset(s.clone());
                self.app.apply(s);
            }
            Err(e) => self.message = Some(format!("{e}. Keeping the current world.")),
        }
    }

    /// Keeps the address bar's fragment current (at most once a second), so copying the
    /// address also shares the view.
    fn write_hash(&mut self, now: f64) {
        if now - self.last_url_write_ms < 1000.0 {
            return;
        }
        self.last_url_write_ms = now;
        let frag = format!("#{}", self.app.share_state().to_fragment());
        if frag != self.last_hash
            && let Some(w) = web_sys::window()
            && let Ok(h) = w.history()
            && h.replace_state_with_url(&JsValue::NULL, "", Some(&frag)).is_ok()
        {
            self.last_hash = frag;
        }
    }

    fn control_input(&self, ctx: &egui::Context, resp: &egui::Response) -> ControlInput {
        let mut input = ControlInput { pinch: 1.0, ..Default::default() };
        let multi = ctx.multi_touch().filter(|m| m.num_touches >= 2);
        if let Some(m) = multi {
            input.pinch = m.zoom_delta;
            input.movement.x = (-m.translation_delta.x / 8.0).clamp(-1.0, 1.0);
            input.movement.z = (m.translation_delta.y / 8.0).clamp(-1.0, 1.0);
        } else if resp.dragged() {
            let d = resp.drag_delta();
            input.look_px = glam::Vec2::new(d.x, d.y);
        }
        if resp.hovered() {
            input.scroll = ctx.input(|i| i.smooth_scroll_delta.y) / 50.0;
        }
        if !ctx.egui_wants_keyboard_input() {
            ctx.input(|i| {
                use egui::Key;
                let axis = |pos: &[Key], neg: &[Key]| {
                    let p = pos.iter().any(|k| i.key_down(*k)) as i32 as f32;
                    let n = neg.iter().any(|k| i.key_down(*k)) as i32 as f32;
                    p - n
                };
                input.movement.x += axis(&[Key::D, Key::ArrowRight], &[Key::A, Key::ArrowLeft]);
                input.movement.z += axis(&[Key::W, Key::ArrowUp], &[Key::S, Key::ArrowDown]);
                input.movement.y += axis(&[Key::E, Key::PageUp], &[Key::Q, Key::PageDown]);
                input.boost = i.modifiers.shift;
            });
        }
        input
    }
}

impl eframe::App for WebApp {
    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        if PAUSED.get() {
            CONTEXT.with(|c| *c.borrow_mut() = Some(ctx));
            return;
        }
        let generation = DEVICE_GEN.load(SeqCst);
        if LOST_DEVICE.load(SeqCst) == generation {
            // Only the first frame after the loss starts the replacement.
            if LOST_DEVICE.compare_exchange(generation, 0, SeqCst, SeqCst).is_ok() {
                let state = self.app.share_state();
                wasm_bindgen_futures::spawn_local(restart(state, "device lost".into()));
            }
            return;
        }
        let now = now_ms();
        let dt_ms = self.last_frame_ms.map(|t| now - t).unwrap_or(16.0);
        self.last_frame_ms = Some(now);
        self.pacer.gpu_done(self.gpu_done.load(SeqCst));
        // An input event may run this while the GPU still draws the previous frame: the app
        // moves on (camera, tiles) and the view keeps the previous picture until it is done.
        let draw = self.pacer.may_draw(now);
        self.follow_hash();

        let Some(rs) = frame.wgpu_render_state() else { return };
        let cpu_start = now_ms();
        self.pump_world();
        self.pump_refinement();
        self.pump_sketch(&ctx);
        TILE_PROBE.with(|p| {
            let mut p = p.borrow_mut();
            if let (Some(c), None) = (p.0, &p.1) {
                p.1 = self.app.tile_heights(c).map(<[f32]>::to_vec);
            }
        });
        egui::CentralPanel::no_frame().show(ui, |ui| {
            let rect = ui.max_rect();
            let resp = ui.allocate_rect(rect, egui::Sense::click_and_drag());
            let size = crate::render::view_size([rect.width(), rect.height()], ctx.pixels_per_point(), self.env.software_adapter);
            let input = self.control_input(&ctx, &resp);
            let (nodes, params) = self.app.frame(&input, dt_ms / 1000.0, size);
            if self.renderer.ensure_target(&rs.device, size) || self.texture.is_none() {
                let view = self.renderer.color_view().expect("target just ensured");
                let mut r = rs.renderer.write();
                match self.texture {
                    Some(id) => r.update_egui_texture_from_wgpu_texture(&rs.device, view, wgpu::FilterMode::Linear, id),
                    None => self.texture = Some(r.register_native_texture(&rs.device, view, wgpu::FilterMode::Linear)),
                }
            }
            if draw {
                let render_start = now_ms();
                let stats = self.renderer.render(&rs.device, &rs.queue, &nodes, &params, MESH_KEEP_FRAMES);
                let render_ms = now_ms() - render_start;
                self.env.uploads = stats.uploads;
                self.env.triangles = stats.triangles;
                self.env.cpu_ms = now_ms() - cpu_start;
                let s = self.app.stats();
                self.frame_work.push_back([self.env.cpu_ms, s.world_ms, s.nodes_ms, render_ms, stats.upload_ms, stats.submit_ms, stats.uploads as f64]);
                if self.frame_work.len() > 120 {
                    self.frame_work.pop_front();
                }
                let (frame, interval) = self.pacer.drawn(now);
                if let Some(ms) = interval {
                    self.app.record_frame_time(ms);
                    FRAME_INTERVALS.with(|f| {
                        let mut f = f.borrow_mut();
                        if f.len() < MAX_FRAME_INTERVALS {
                            f.push(ms);
                        }
                    });
                }
                // eframe paints the overlay (one more submit) after this returns, in the same
                // task; a microtask asks for "work done" after that paint.
                let (queue, done, ctx) = (rs.queue.clone(), self.gpu_done.clone(), ctx.clone());
                wasm_bindgen_futures::spawn_local(async move {
                    queue.on_submitted_work_done(move || {
                        done.fetch_max(frame, SeqCst);
                        repaint_once(&ctx);
                    });
                });
            }
            if let Some(id) = self.texture {
                ui.painter().image(id, rect, egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)), egui::Color32::WHITE);
            }
        });

        {
            let ml = self.ml.borrow();
            self.env.ml_status = ml.status.clone();
            self.env.tem_loading = ml.loading.map(|k| (k, LEVELS));
            self.env.tem_error = ml.error.clone();
            self.env.tem_ready = ml.tem.is_some();
            self.env.sketch_backend = if ml.sketch_gpu.is_some() { "WebGPU" } else { "CPU worker" };
        }
        self.env.source = self.app.source_name();
        let mode = self.app.controller.mode;
        let copied = self.copied_at_ms.is_some_and(|t| now - t < 2000.0);
        let stats = self.app.stats().clone();
        let mut speed = self.app.controller.speed_mps;
        let mut show_lod = self.app.show_lod;
        let mut refine_on = self.refine_on;
        let act = self.overlay.show(&ctx, &stats, &self.env, mode, &mut speed, &mut show_lod, &mut refine_on, self.message.as_deref(), copied);
        self.refine_on = refine_on;
        self.app.controller.speed_mps = speed;
        self.app.show_lod = show_lod;
        if let Some(m) = act.mode {
            let cam = self.app.camera;
            self.app.controller.set_mode(m, &cam);
        }
        if let Some(s) = act.settings {
            self.app.apply_settings(s);
        }
        if act.dismiss_message {
            self.message = None;
        }
        if self.app.source() == crate::world::SourceKind::Sketch {
            let busy = self.ml.borrow().sketch_busy || self.app.stats().sketch_jobs.in_flight > 0;
            let relief = self.app.settings().relief_m;
            let sk = self.sketch_panel.show(&ctx, &mut self.app.canvas, relief, busy, &self.examples);
            self.sketch_actions(sk);
            if let Some(Ok(w)) = WORKER.with(|w| w.borrow().clone()) {
                self.start_sketch_jobs(&w);
            }
        }
        if act.copy_link {
            self.last_url_write_ms = 0.0;
            self.write_hash(now);
            let href = web_sys::window().and_then(|w| w.location().href().ok()).unwrap_or_default();
            let page = href.split('#').next().unwrap_or_default();
            match self.app.share_state().share_fragment() {
                Ok(f) => ctx.copy_text(format!("{page}#{f}")),
                Err(too_long) => {
                    // The sketch goes as a file; the link copied carries everything else.
                    let saved = download_sketch(self.app.canvas.sketch());
                    ctx.copy_text(format!("{page}#{}", too_long.without_sketch));
                    self.link_too_long += 1;
                    self.message = Some(match saved {
                        Ok(()) => format!("{too_long}. The link copied has everything but the sketch, which was downloaded as sketch.png: send both; the receiver opens the link, then Import PNG."),
                        Err(e) => format!("{too_long}, and the sketch could not be downloaded ({e}). Use Export PNG in the sketch panel."),
                    });
                }
            }
            self.copied_at_ms = Some(now);
        }
        self.write_hash(now);

        let link = self.app.share_state().to_fragment();
        let json = serde_json::json!({
            "stats": stats,
            "adapter": self.env.adapter,
            "ml_status": self.env.ml_status,
            "tem_ready": self.env.tem_ready,
            "tem_error": self.env.tem_error,
            "source": self.env.source,
            "uploads": self.env.uploads,
            "triangles": self.env.triangles,
            "cpu_ms": self.env.cpu_ms,
            // The frame with the most main-thread work of the last 120: [total, tiles, nodes,
            // drawing, of which uploads, of which encoding + submit] ms, then meshes uploaded.
            "cpu_ms_worst": self.frame_work.iter().copied().max_by(|a, b| a[0].total_cmp(&b[0])),
            "message": self.message,
            "device_restarts": RESTARTS.get(),
            "link": link,
            "mode": format!("{:?}", mode),
            // The sketch canvas on screen (CSS pixels: x, y, width, height), for tests that
            // draw on it.
            "sketch_canvas": self.sketch_panel.canvas_rect.filter(|_| self.app.source() == crate::world::SourceKind::Sketch).map(|r| [r.min.x, r.min.y, r.width(), r.height()]),
            "sketch_models": format!("{:?}", self.app.sketch_models()),
            "sketch_backend": self.env.sketch_backend,
            "sketch_variants": self.sketch_panel.variant_count(),
            "sketch_blends": self.ml.borrow().blends,
            "link_too_long": self.link_too_long,
            "copy_link_button": self.overlay.copy_link_rect.map(|r| [r.min.x, r.min.y, r.width(), r.height()]),
            "software_adapter": self.env.software_adapter,
            // The CPU worker's rest per ms of work (runtime::worker_rest_per_work).
            "worker_rest_per_work": self.env.worker_rest_per_work,
            "sketch_buttons": self.sketch_panel.buttons.iter().map(|(k, r)| (k.clone(), [r.min.x, r.min.y, r.width(), r.height()])).collect::<std::collections::BTreeMap<_, _>>(),
        });
        STATS_JSON.with(|s| *s.borrow_mut() = json.to_string());
        if self.pacer.waiting() {
            // The GPU's "work done" asks for the next frame; this is the fallback.
            ctx.request_repaint_after(std::time::Duration::from_millis(crate::render::pacing::GPU_STALL_MS as u64));
        } else {
            repaint_once(&ctx);
        }
    }
}

