//! The browser shell: opens the one wgpu device that rendering and burn share (WebGPU, else
//! WebGL2 for drawing with the networks on the CPU worker), starts the CPU worker, and runs
//! the page ([`PageShell`]) inside eframe. It only
//! moves bytes: fetches, posts to the worker or the GPU, and hands back what came of it
//! ([`shell`]); everything it decides is in the core, tested natively.

mod files;
mod hooks;
mod shell;
mod worker;

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::atomic::Ordering::SeqCst;

use wasm_bindgen::JsCast;
use wasm_bindgen::prelude::*;

use crate::app::runners::Port;
use crate::models;
use crate::render::device::{self, DeviceWatch, Opened};
use crate::share::ShareState;
use crate::ui::shell::PageShell;

const NO_GPU: &str = "This page needs WebGPU or WebGL2 to draw, and this browser offers neither. Try a current Chrome, Edge, Firefox or Safari, or turn on hardware acceleration in the browser's settings.";

/// What burn is told where the page draws with WebGL2.
const NO_COMPUTE: &str = "WebGL2 has no compute shaders: the networks run on the CPU worker";

thread_local! {
    /// The running eframe runner and the GPU device it draws with (replaced after a loss).
    static RUNNER: RefCell<Option<eframe::WebRunner>> = const { RefCell::new(None) };
    static DEVICE: RefCell<Option<wgpu::Device>> = const { RefCell::new(None) };
    /// The CPU worker (kept across device restarts), or why there is none.
    static WORKER: RefCell<Option<Result<Rc<worker::CpuWorker>, String>>> = const { RefCell::new(None) };
}

/// The page's devices and their loss.
static DEVICES: DeviceWatch = DeviceWatch::new();

/// The page's runners: the CPU worker, the GPU and the main thread.
type Runners = crate::app::runners::Runners<worker::CpuWorker>;

/// Destroys the page's GPU device, as a driver reset would: only the device's own lost
/// callback tells the page (the end-to-end test shows it recovers); `false` if there is none.
#[wasm_bindgen]
pub fn terrain_lose_device() -> bool {
    DEVICE.with(|d| d.borrow().as_ref().map(|d| d.destroy()).is_some())
}

/// Replaces the lost device: stops the old renderer and starts the page again at `state`, with
/// the terrain that was pinned (`pinned`: its file's name and tiles).
async fn restart(state: ShareState, pinned: Option<(String, crate::world::pins::Pins)>, why: String) {
    RUNNER.with(|r| r.borrow_mut().take()).inspect(|r| r.destroy());
    let note = format!("The GPU device was lost ({why}); the page started a new one and kept the view.");
    if let Err(e) = run(Some(crate::app::page::Kept { share: state, note, pinned })).await {
        show_page_message(&format!("The GPU device was lost and a new one could not be started: {e}"), false);
    }
}

/// The page's CPU worker, started once (and kept when a lost device restarts the page).
fn cpu_worker() -> Result<Rc<worker::CpuWorker>, String> {
    if let Some(w) = WORKER.with(|w| w.borrow().clone())
        && w.as_ref().map_or(true, |w| w.gone().is_none())
    {
        return w;
    }
    let w = worker::CpuWorker::start().map(Rc::new);
    WORKER.with(|slot| *slot.borrow_mut() = Some(w.clone()));
    w
}

/// The browser's description of its WebGPU adapter (`adapter.info`'s vendor, architecture and
/// description) and whether it says it is a fallback adapter.
async fn browser_adapter_info() -> Option<(String, bool)> {
    use js_sys::Reflect;
    let gpu = Reflect::get(&web_sys::window()?.navigator(), &"gpu".into()).ok()?;
    let request = Reflect::get(&gpu, &"requestAdapter".into()).ok()?.dyn_into::<js_sys::Function>().ok()?;
    let adapter = wasm_bindgen_futures::JsFuture::from(request.call0(&gpu).ok()?.dyn_into::<js_sys::Promise>().ok()?).await.ok()?;
    let info = Reflect::get(&adapter, &"info".into()).ok()?;
    let field = |k: &str| Reflect::get(&info, &k.into()).ok().and_then(|v| v.as_string()).unwrap_or_default();
    let text = [field("vendor"), field("architecture"), field("description")].into_iter().filter(|s| !s.is_empty()).collect::<Vec<_>>().join(" ");
    Some((text, Reflect::get(&info, &"isFallbackAdapter".into()).ok().and_then(|v| v.as_bool()).unwrap_or(false)))
}

unsafe extern "C" {
    /// The module's static constructors (burn's GPU compiler registrations), from the linker.
    fn __wasm_call_ctors();
}

/// Page (and CPU worker) entry point: the first call into the module after instantiation.
#[wasm_bindgen(start)]
pub fn start() {
    // The static constructors run once, here. Without this explicit call the linker wraps
    // every export in a call to them: every call from JavaScript into the module ran them all
    // again — over a third of the page's main-thread time.
    // SAFETY: called once, first thing after instantiation, before any code that reads what
    // the constructors register.
    unsafe { __wasm_call_ctors() };
    std::panic::set_hook(Box::new(|info| {
        console_error_panic_hook::hook(info);
        // The worker has no page: its trap reaches the page as a dead worker instead. A later
        // panic (the module's state is broken after the first) changes nothing.
        static SHOWN: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
        if web_sys::window().is_some() && !SHOWN.swap(true, SeqCst) {
            show_page_message(&crate::app::page::stopped_message(&info.to_string()), true);
        }
    }));
    // The same module also runs in the CPU worker, which has no page to start.
    if web_sys::window().is_none() {
        return;
    }
    wasm_bindgen_futures::spawn_local(async {
        if let Err(e) = run(None).await {
            show_page_message(&e, false);
        }
    });
}

/// Shows `text` in the page's message box (outside the canvas, so it works without WebGPU),
/// with a Reload button after a panic.
fn show_page_message(text: &str, reload: bool) {
    web_sys::console::warn_1(&text.into());
    let Some(doc) = web_sys::window().and_then(|w| w.document()) else { return };
    if let Some(el) = doc.get_element_by_id("message") {
        el.set_text_content(Some(text));
        let _ = el.set_attribute("style", "display:block");
        if reload && let Ok(button) = doc.create_element("button") {
            button.set_text_content(Some("Reload"));
            button.set_id("reload");
            let _ = button.set_attribute("onclick", "location.reload()");
            let _ = el.append_child(&button);
        }
    }
    if let Some(el) = doc.get_element_by_id("loading") {
        let _ = el.set_attribute("style", "display:none");
    }
}

fn location_hash() -> String {
    web_sys::window().and_then(|w| w.location().hash().ok()).unwrap_or_default()
}

/// The device the page draws with, and whether it is WebGPU's: the browser's WebGPU adapter,
/// else a WebGL2 context on `canvas` (said in the console); the error names why each failed.
async fn open_device(canvas: &web_sys::HtmlCanvasElement) -> Result<(Opened, bool), String> {
    let webgpu =
        if wgpu::util::is_browser_webgpu_supported().await { device::open(wgpu::Backends::BROWSER_WEBGPU).await } else { Err("this browser does not offer it".to_string()) };
    let why_not = match webgpu {
        Ok(opened) => return Ok((opened, true)),
        Err(e) => e,
    };
    match device::open_webgl(canvas).await {
        Ok(opened) => {
            web_sys::console::info_1(&format!("No WebGPU ({why_not}): drawing with WebGL2, the networks on the CPU worker.").into());
            Ok((opened, false))
        }
        Err(e) => Err(format!("{NO_GPU} (WebGPU: {why_not}; WebGL2: {e})")),
    }
}

/// Whether the page's main pointer is coarse (a finger: `(pointer: coarse)`).
fn coarse_pointer() -> bool {
    web_sys::window().and_then(|w| w.match_media("(pointer: coarse)").ok().flatten()).is_some_and(|m| m.matches())
}

/// Starts the page: the view from the link, or `restart` (the view, a note and the pins to keep) after
/// a lost device. The view starts at once; the models join the core as they load.
async fn run(restart: Option<crate::app::page::Kept>) -> Result<(), String> {
    let window = web_sys::window().ok_or("no window")?;
    let document = window.document().ok_or("no document")?;
    let canvas: web_sys::HtmlCanvasElement =
        document.get_element_by_id("terrain_canvas").ok_or("the page has no #terrain_canvas")?.dyn_into().map_err(|_| "#terrain_canvas is not a canvas")?;
    let (Opened { instance, adapter, device, queue }, webgpu) = open_device(&canvas).await?;
    let generation = DEVICES.new_device();
    device.set_device_lost_callback(move |_, _| DEVICES.lost(generation));
    DEVICE.with(|d| *d.borrow_mut() = Some(device.clone()));
    let info = adapter.get_info();
    let (api, browser) = if webgpu { ("WebGPU", browser_adapter_info().await) } else { ("WebGL2", None) };
    let adapter_name = crate::ui::adapter_name(api, [&info.name, &info.driver, &info.driver_info], browser);
    // burn on the same device, if it has compute shaders and its self-check passes.
    let burn = if webgpu {
        let setup = models::WgpuSetup { instance: instance.clone(), adapter: adapter.clone(), device: device.clone(), queue: queue.clone(), backend: wgpu::Backend::BrowserWebGpu };
        models::start_burn(setup).await
    } else {
        Err(NO_COMPUTE.to_string())
    };
    let query = window.location().search().unwrap_or_default();
    let mut page = PageShell::start(Rc::new(shell::WebPlatform), burn, adapter_name, cpu_worker(), &query, restart);
    page.device_restarts = DEVICES.restarts();
    hooks::PROBES.with(|p| *p.borrow_mut() = Some((page.probes.clone(), page.runners().clone())));
    let options = eframe::WebOptions {
        wgpu_options: eframe::egui_wgpu::WgpuConfiguration {
            wgpu_setup: eframe::egui_wgpu::WgpuSetup::Existing(eframe::egui_wgpu::WgpuSetupExisting { instance, adapter, device, queue }),
            ..Default::default()
        },
        ..Default::default()
    };
    let web_runner = eframe::WebRunner::new();
    let app = Box::new(move |cc: &eframe::CreationContext<'_>| -> Result<Box<dyn eframe::App>, Box<dyn std::error::Error + Send + Sync>> {
        cc.wgpu_render_state.as_ref().ok_or("eframe started without wgpu")?;
        crate::ui::set_up(&cc.egui_ctx, coarse_pointer());
        Ok(Box::new(shell::WebApp(page)))
    });
    web_runner.start(canvas, options, app).await.map_err(|e| format!("The page could not start its renderer: {e:?}"))?;
    RUNNER.with(|r| *r.borrow_mut() = Some(web_runner));
    if let Some(el) = document.get_element_by_id("loading") {
        let _ = el.set_attribute("style", "display:none");
    }
    Ok(())
}
