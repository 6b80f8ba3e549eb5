//! The egui shell: each frame it hands the core what came back, carries out what the core
//! asks (fetches and requests, as tasks), draws the 3-D view and the overlay, and keeps the
//! link in the address bar.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::atomic::Ordering::SeqCst;

use wasm_bindgen::prelude::*;

use super::hooks::{self, STATS_JSON, TEM_PROBE, TILE_PROBE, TemProbe};
use super::{DEVICE_GEN, LOST_DEVICE, RESTARTS, Runners, files, location_hash, now_ms};
use crate::app::MESH_KEEP_FRAMES;
use crate::app::page::{Delivery, Effect, PageCore};
use crate::app::runners::Port;
use crate::render::gpu::TerrainRenderer;
use crate::share::ShareState;
use crate::sketch::Sketch;
use crate::ui::Environment;
use crate::ui::page::{BrowserAsks, PageUi};

/// The page's eframe app: the core, its runners, the overlay and the 3-D view's renderer.
pub(super) struct WebApp {
    core: PageCore,
    runners: Rc<Runners>,
    ui: PageUi,
    renderer: TerrainRenderer,
    env: Environment,
    s: ShellState,
}

/// What the shell keeps between frames.
#[derive(Default)]
struct ShellState {
    /// What came back from fetches and runners since the last frame.
    inbox: Rc<RefCell<Vec<Delivery>>>,
    texture: Option<egui::TextureId>,
    last_frame_ms: Option<f64>,
    /// Draws a frame of the 3-D view only once the GPU has finished the previous one.
    pacer: crate::render::FramePacer,
    /// The newest frame whose GPU work is done (set by the queue's callback).
    gpu_done: std::sync::Arc<std::sync::atomic::AtomicU64>,
    /// The main thread's work per frame over the last 120 frames: total, tiles, nodes and
    /// drawing ms, the upload and submit parts of the drawing (ms), and the meshes uploaded.
    frame_work: std::collections::VecDeque<[f64; 7]>,
    /// Times "Copy link" found the sketch too detailed for a link and sent it as a file.
    link_too_long: u32,
    /// A sketch PNG the user opened (or why it could not be read), once it is read.
    import: Rc<RefCell<Option<Result<Sketch, String>>>>,
}

impl WebApp {
    /// The app for `core`, with its runners, drawing on `rs`'s device.
    pub fn new(core: PageCore, runners: Rc<Runners>, share: ShareState, env: Environment, rs: &eframe::egui_wgpu::RenderState) -> Self {
        Self { core, runners, ui: PageUi::new(share), renderer: TerrainRenderer::new(&rs.device), env, s: ShellState::default() }
    }
}

/// Asks for one more frame. egui answers `request_repaint()` with two; a non-zero delay asks
/// for exactly one, at the next animation frame.
fn repaint_once(ctx: &egui::Context) {
    ctx.request_repaint_after(std::time::Duration::from_micros(1));
}

impl WebApp {
    /// Hands the core what came back (and a worker that died meanwhile).
    fn deliver(&mut self) {
        if let Some(why) = self.runners.worker.as_ref().and_then(|w| w.gone())
            && self.core.worker().is_ok()
        {
            self.core.deliver(Delivery::WorkerGone { id: 0, why });
        }
        for d in std::mem::take(&mut *self.s.inbox.borrow_mut()) {
            self.core.deliver(d);
        }
    }

    /// Carries out what the core asks: each fetch and request becomes a task whose result
    /// lands in the inbox.
    fn carry_out(&mut self) {
        for note in self.core.console.drain(..) {
            web_sys::console::warn_1(&note.into());
        }
        for e in self.core.take_effects() {
            let (inbox, runners) = (self.s.inbox.clone(), self.runners.clone());
            wasm_bindgen_futures::spawn_local(async move {
                let d = match e {
                    Effect::Fetch { id, url } => Delivery::Fetched { id, bytes: files::fetch(&url).await },
                    Effect::Post { target, envelope } => runners.call(target, envelope).await,
                };
                inbox.borrow_mut().push(d);
            });
        }
        let probe = self.core.loads.tem.is_ready().then(|| TemProbe {
            runners: self.runners.clone(),
            target: self.core.tem_target(),
            backend: self.core.tem_backend(),
            epoch: self.core.app.epoch(),
        });
        TEM_PROBE.with(|p| *p.borrow_mut() = probe);
    }

    /// The sketch panel's files: a download, a file to pick, a picked file that arrived.
    fn sketch_files(&mut self, asks: BrowserAsks) {
        if asks.export_sketch
            && let Err(e) = files::download_sketch(self.core.app.canvas.sketch())
        {
            self.core.message = Some(format!("The sketch could not be exported: {e}"));
        }
        if asks.import_sketch
            && let Err(e) = files::pick_sketch_file(self.s.import.clone())
        {
            self.core.message = Some(format!("No file dialog: {e}"));
        }
        match self.s.import.borrow_mut().take() {
            Some(Ok(s)) => self.core.app.canvas.load(s),
            Some(Err(e)) => self.core.message = Some(e),
            None => {}
        }
    }

    /// Keeps the address bar's fragment current (`force`: now), so copying it shares the view.
    fn write_link(&mut self, now: f64, force: bool) {
        if let Some(frag) = self.core.link_to_write(now, force)
            && let Some(h) = web_sys::window().and_then(|w| w.history().ok())
        {
            let _ = h.replace_state_with_url(&JsValue::NULL, "", Some(&frag));
        }
    }

    /// "Copy link": the address with the view; a sketch too detailed for a link goes as a file.
    fn copy_link(&mut self, ctx: &egui::Context, now: f64) {
        self.write_link(now, true);
        let href = web_sys::window().and_then(|w| w.location().href().ok()).unwrap_or_default();
        let (text, file) = self.core.copy_link(href.split('#').next().unwrap_or_default());
        ctx.copy_text(text);
        if let Some(sketch) = file {
            self.s.link_too_long += 1;
            if let Err(e) = files::download_sketch(&sketch) {
                self.core.message = Some(format!("The sketch could not be downloaded ({e}): use Export PNG in the sketch panel."));
            }
        }
        self.ui.copied_at_ms = Some(now);
    }

    /// Draws the 3-D view (when the GPU has finished the previous frame) into the panel.
    fn view(&mut self, ui: &mut egui::Ui, rs: &eframe::egui_wgpu::RenderState, dt_ms: f64, now: f64, cpu_start: f64) {
        let ctx = ui.ctx().clone();
        let draw = self.s.pacer.may_draw(now);
        let rect = ui.max_rect();
        let resp = ui.allocate_rect(rect, egui::Sense::click_and_drag());
        let size = crate::render::view_size([rect.width(), rect.height()], ctx.pixels_per_point(), self.env.software_adapter);
        let input = crate::ui::control_input(&ctx, &resp);
        let (nodes, params) = self.core.app.frame(&input, dt_ms / 1000.0, size);
        if self.renderer.ensure_target(&rs.device, size) || self.s.texture.is_none() {
            let view = self.renderer.color_view().expect("target just ensured");
            let mut r = rs.renderer.write();
            match self.s.texture {
                Some(id) => r.update_egui_texture_from_wgpu_texture(&rs.device, view, wgpu::FilterMode::Linear, id),
                None => self.s.texture = Some(r.register_native_texture(&rs.device, view, wgpu::FilterMode::Linear)),
            }
        }
        if draw {
            let render_start = now_ms();
            let stats = self.renderer.render(&rs.device, &rs.queue, &nodes, &params, MESH_KEEP_FRAMES);
            let render_ms = now_ms() - render_start;
            (self.env.uploads, self.env.triangles, self.env.cpu_ms) = (stats.uploads, stats.triangles, now_ms() - cpu_start);
            let s = self.core.app.stats();
            self.s.frame_work.push_back([self.env.cpu_ms, s.world_ms, s.nodes_ms, render_ms, stats.upload_ms, stats.submit_ms, stats.uploads as f64]);
            if self.s.frame_work.len() > 120 {
                self.s.frame_work.pop_front();
            }
            let (frame, interval) = self.s.pacer.drawn(now);
            if let Some(ms) = interval {
                self.core.app.record_frame_time(ms);
                hooks::record_frame_interval(ms);
            }
            // eframe paints the overlay (one more submit) after this returns, in the same
            // task; a microtask asks for "work done" after that paint.
            let (queue, done, ctx) = (rs.queue.clone(), self.s.gpu_done.clone(), ctx.clone());
            wasm_bindgen_futures::spawn_local(async move {
                queue.on_submitted_work_done(move || {
                    done.fetch_max(frame, SeqCst);
                    repaint_once(&ctx);
                });
            });
        }
        if let Some(id) = self.s.texture {
            ui.painter().image(id, rect, egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)), egui::Color32::WHITE);
        }
    }
}

impl eframe::App for WebApp {
    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        if hooks::PAUSED.get() {
            hooks::CONTEXT.with(|c| *c.borrow_mut() = Some(ctx));
            return;
        }
        let generation = DEVICE_GEN.load(SeqCst);
        if LOST_DEVICE.load(SeqCst) == generation {
            // Only the first frame after the loss starts the replacement.
            if LOST_DEVICE.compare_exchange(generation, 0, SeqCst, SeqCst).is_ok() {
                wasm_bindgen_futures::spawn_local(super::restart(self.core.app.share_state(), "device lost".into()));
            }
            return;
        }
        let now = now_ms();
        let dt_ms = self.s.last_frame_ms.map(|t| now - t).unwrap_or(16.0);
        self.s.last_frame_ms = Some(now);
        self.s.pacer.gpu_done(self.s.gpu_done.load(SeqCst));
        if let Some(s) = self.core.follow_link(&location_hash()) {
            self.ui.overlay.reset(s);
        }
        let Some(rs) = frame.wgpu_render_state() else { return };
        let cpu_start = now_ms();
        self.deliver();
        self.core.start_work(now);
        self.carry_out();
        TILE_PROBE.with(|p| {
            let mut p = p.borrow_mut();
            if let (Some(c), None) = (p.0, &p.1) {
                p.1 = self.core.app.tile_heights(c).map(<[f32]>::to_vec);
            }
        });
        egui::CentralPanel::no_frame().show(ui, |ui| self.view(ui, rs, dt_ms, now, cpu_start));
        self.env.take_core(&self.core);
        let asks = self.ui.show(&ctx, &mut self.core, &self.env, now);
        self.sketch_files(asks);
        // A stroke goes out in the frame that drew it.
        self.core.start_sketch_jobs();
        self.carry_out();
        if asks.copy_link {
            self.copy_link(&ctx, now);
        }
        self.write_link(now, false);
        let json = self.ui.stats_json(&self.core, &self.env, &self.s.frame_work, RESTARTS.get(), self.s.link_too_long);
        STATS_JSON.with(|s| *s.borrow_mut() = json);
        if self.s.pacer.waiting() {
            // The GPU's "work done" asks for the next frame; this is the fallback.
            ctx.request_repaint_after(std::time::Duration::from_millis(crate::render::pacing::GPU_STALL_MS as u64));
        } else {
            repaint_once(&ctx);
        }
    }
}
