//! The browser shell: checks for WebGPU, creates the one wgpu device that rendering and burn
//! share, reads the share link, and runs the app inside eframe. Everything it calls is
//! testable natively; this file only glues browser events to it.

use std::cell::RefCell;
use std::rc::Rc;

use wasm_bindgen::JsCast;
use wasm_bindgen::prelude::*;

use crate::app::{MESH_KEEP_FRAMES, TerrainApp};
use crate::models;
use crate::render::camera::ControlInput;
use crate::render::gpu::TerrainRenderer;
use crate::share::ShareState;
use crate::ui::{Environment, Overlay};

const NO_WEBGPU: &str = "This page needs WebGPU, which this browser does not offer. Try a current Chrome, Edge or Safari (or enable WebGPU in the browser's settings).";

thread_local! {
    static STATS_JSON: RefCell<String> = RefCell::new("{}".into());
}

/// The latest frame statistics as JSON (read by the end-to-end test and usable from the
/// browser console).
#[wasm_bindgen]
pub fn terrain_stats() -> String {
    STATS_JSON.with(|s| s.borrow().clone())
}

/// Page entry point.
#[wasm_bindgen(start)]
pub fn start() {
    console_error_panic_hook::set_once();
    wasm_bindgen_futures::spawn_local(async {
        if let Err(e) = run().await {
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

async fn run() -> Result<(), String> {
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
    let info = adapter.get_info();
    let label = [&info.name, &info.driver, &info.driver_info].into_iter().find(|s| !s.is_empty()).cloned().unwrap_or_else(|| "browser adapter".into());
    let adapter_name = format!("WebGPU · {label}");

    let ml_status = Rc::new(RefCell::new("starting burn on the GPU…".to_string()));
    match models::device_from_setup(models::WgpuSetup { instance: instance.clone(), adapter: adapter.clone(), device: device.clone(), queue: queue.clone(), backend: wgpu::Backend::BrowserWebGpu }) {
        Ok(ml_device) => {
            let status = ml_status.clone();
            wasm_bindgen_futures::spawn_local(async move {
                let t0 = now_ms();
                let text = match models::self_check(&ml_device).await {
                    Ok(err) if err < 1e-3 => format!("burn wgpu ready (self-check {:.0} ms, max |Δ| {err:.1e} m)", now_ms() - t0),
                    Ok(err) => format!("burn wgpu gives wrong results (max |Δ| {err} m)"),
                    Err(e) => format!("burn wgpu failed: {e}"),
                };
                *status.borrow_mut() = text;
            });
        }
        Err(e) => *ml_status.borrow_mut() = e,
    }

    let hash = location_hash();
    let (share, message) = match ShareState::from_fragment(&hash) {
        Ok(s) => (s, None),
        Err(e) => (ShareState::default(), Some(format!("{e}. Showing the default world instead."))),
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
                    env: Environment { adapter: adapter_name, ..Default::default() },
                    ml_status,
                    message,
                    last_frame_ms: None,
                    last_hash: hash,
                    last_url_write_ms: 0.0,
                    copied_at_ms: None,
                }))
            }),
        )
        .await
        .map_err(|e| format!("The page could not start its renderer: {e:?}"))?;
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
    ml_status: Rc<RefCell<String>>,
    message: Option<String>,
    last_frame_ms: Option<f64>,
    last_hash: String,
    last_url_write_ms: f64,
    copied_at_ms: Option<f64>,
}

impl WebApp {
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
        let now = now_ms();
        let dt_ms = self.last_frame_ms.map(|t| now - t).unwrap_or(16.0);
        self.last_frame_ms = Some(now);
        self.app.record_frame_time(dt_ms);
        self.follow_hash();

        let Some(rs) = frame.wgpu_render_state() else { return };
        let cpu_start = now_ms();
        egui::CentralPanel::no_frame().show(ui, |ui| {
            let rect = ui.max_rect();
            let resp = ui.allocate_rect(rect, egui::Sense::click_and_drag());
            let ppp = ctx.pixels_per_point();
            let size = [(rect.width() * ppp).round().max(1.0) as u32, (rect.height() * ppp).round().max(1.0) as u32];
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
            let stats = self.renderer.render(&rs.device, &rs.queue, &nodes, &params, MESH_KEEP_FRAMES);
            self.env.uploads = stats.uploads;
            self.env.triangles = stats.triangles;
            self.env.cpu_ms = now_ms() - cpu_start;
            if let Some(id) = self.texture {
                ui.painter().image(id, rect, egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)), egui::Color32::WHITE);
            }
        });

        self.env.ml_status = self.ml_status.borrow().clone();
        self.env.source = self.app.source_name();
        let mode = self.app.controller.mode;
        let copied = self.copied_at_ms.is_some_and(|t| now - t < 2000.0);
        let stats = self.app.stats().clone();
        let mut speed = self.app.controller.speed_mps;
        let mut show_lod = self.app.show_lod;
        let act = self.overlay.show(&ctx, &stats, &self.env, mode, &mut speed, &mut show_lod, self.message.as_deref(), copied);
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
        if act.copy_link {
            self.last_url_write_ms = 0.0;
            self.write_hash(now);
            if let Some(href) = web_sys::window().and_then(|w| w.location().href().ok()) {
                ctx.copy_text(href);
                self.copied_at_ms = Some(now);
            }
        }
        self.write_hash(now);

        let link = self.app.share_state().to_fragment();
        let json = serde_json::json!({
            "stats": stats,
            "adapter": self.env.adapter,
            "ml_status": self.env.ml_status,
            "source": self.env.source,
            "uploads": self.env.uploads,
            "triangles": self.env.triangles,
            "cpu_ms": self.env.cpu_ms,
            "message": self.message,
            "link": link,
            "mode": format!("{:?}", mode),
        });
        STATS_JSON.with(|s| *s.borrow_mut() = json.to_string());
        ctx.request_repaint();
    }
}
