//! The page's side of each frame: the [`Platform`] of a web page (fetches, microtasks, the
//! address bar, files, the console) and the eframe app that runs the platform-free
//! [`PageShell`] each frame, after the check only a page has (its GPU device lost).

use wasm_bindgen::prelude::*;

use super::worker::CpuWorker;
use super::{DEVICES, files, location_hash};
use crate::ui::shell::{Fetching, FileSlot, PageShell, Picked, Platform, Task, ViewGpu};

/// A web page as the shell's platform.
pub(super) struct WebPlatform;

impl Platform for WebPlatform {
    type Worker = CpuWorker;

    fn spawn(&self, task: Task) {
        wasm_bindgen_futures::spawn_local(task);
    }

    fn fetch(&self, url: &str) -> Fetching {
        let url = url.to_string();
        Box::pin(async move { files::fetch(&url).await })
    }

    fn fragment(&self) -> String {
        location_hash()
    }

    fn set_fragment(&self, fragment: &str) {
        let history = web_sys::window().and_then(|w| w.history().ok());
        let _ = history.map(|h| h.replace_state_with_url(&JsValue::NULL, "", Some(fragment)));
    }

    fn address(&self) -> String {
        let href = web_sys::window().and_then(|w| w.location().href().ok()).unwrap_or_default();
        href.split('#').next().unwrap_or_default().to_string()
    }

    fn warn(&self, note: &str) {
        web_sys::console::warn_1(&note.into());
    }

    fn download(&self, name: &str, bytes: &[u8], mime: &str) -> Result<(), String> {
        files::download(name, bytes, mime)
    }

    fn pick_file(&self, accept: &str, max_bytes: f64, slot: FileSlot) -> Result<(), String> {
        files::pick_file(accept, max_bytes, slot)
    }

    fn read_dropped(&self, file: egui::DroppedFileHandle, max_bytes: f64, landed: std::rc::Rc<std::cell::RefCell<Vec<Picked>>>) {
        files::read_dropped(file, max_bytes, landed);
    }
}

/// The page's eframe app.
pub(super) struct WebApp(pub PageShell<WebPlatform>);

impl eframe::App for WebApp {
    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        if DEVICES.take_loss() {
            wasm_bindgen_futures::spawn_local(super::restart(self.0.core.app.share_state(), self.0.core.kept_pins(), "device lost".into()));
            return;
        }
        if fit_canvas() {
            // This frame was laid out for the canvas's old size: the next one, at once, is not.
            ui.ctx().request_repaint();
            return;
        }
        let Some(rs) = frame.wgpu_render_state() else { return };
        let mut show = |view: &wgpu::TextureView, id: Option<egui::TextureId>| {
            let mut r = rs.renderer.write();
            match id {
                Some(id) => {
                    r.update_egui_texture_from_wgpu_texture(&rs.device, view, wgpu::FilterMode::Linear, id);
                    id
                }
                None => r.register_native_texture(&rs.device, view, wgpu::FilterMode::Linear),
            }
        };
        self.0.frame(ui, Some(ViewGpu { device: &rs.device, queue: &rs.queue, adapter: &rs.adapter, show: &mut show }));
    }
}

/// Keeps the canvas's backing store at its CSS size × the device pixel ratio
/// ([`crate::render::canvas_backing`]): the UI at its size in CSS pixels, the view sharp.
/// Returns whether it resized the canvas.
fn fit_canvas() -> bool {
    use wasm_bindgen::JsCast;
    let Some(window) = web_sys::window() else { return false };
    let Some(canvas) = window.document().and_then(|d| d.get_element_by_id("terrain_canvas")).and_then(|e| e.dyn_into::<web_sys::HtmlCanvasElement>().ok()) else {
        return false;
    };
    let css = [canvas.client_width() as f64, canvas.client_height() as f64];
    let Some([w, h]) = crate::render::canvas_backing(css, window.device_pixel_ratio(), [canvas.width(), canvas.height()]) else { return false };
    canvas.set_width(w);
    canvas.set_height(h);
    true
}
