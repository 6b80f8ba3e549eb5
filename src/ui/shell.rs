//! The page's frame, platform-free: each frame it hands the core what came back, carries out
//! what the core asks (fetches and requests, as tasks of the [`Platform`]), draws the 3-D view
//! and the overlay, and keeps the link in the address bar. The browser supplies a
//! [`Platform`] (fetch, spawn, the address bar, files) and the GPU; the native tests supply
//! files, a thread runner and no GPU, and drive the same frames.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::pin::Pin;
use std::rc::Rc;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering::SeqCst};

use crate::app::MESH_KEEP_FRAMES;
use crate::app::page::{Delivery, Effect, Kept, PageCore, PageStart, Target};
use crate::app::runners::{Port, Runners};
use crate::grid::TileCoord;
use crate::render::gpu::TerrainRenderer;
use crate::share::ShareState;
use crate::sketch::Sketch;
use crate::ui::Environment;
use crate::ui::page::{BrowserAsks, PageUi};

/// A task the platform runs on this thread (the page: a microtask).
pub type Task = Pin<Box<dyn Future<Output = ()>>>;
/// A download's body, or why there is none.
pub type Fetching = Pin<Box<dyn Future<Output = Result<Vec<u8>, String>>>>;
/// Where a file the user picked lands once it is read.
pub type FileSlot = Rc<RefCell<Option<Picked>>>;

/// A file the user picked: its name and bytes, or why they were not read.
#[derive(Clone, Debug, PartialEq)]
pub struct Picked {
    /// The file's name.
    pub name: String,
    /// Its bytes.
    pub bytes: Result<Vec<u8>, Refused>,
}

/// Why a picked file's bytes were not read.
#[derive(Clone, Debug, PartialEq)]
pub enum Refused {
    /// It is larger than asked for (its size, bytes): refused before a byte of it is read.
    TooBig(f64),
    /// The platform could not read it (why).
    Unreadable(String),
}

/// Largest sketch PNG read (bytes): a 256×256 PNG is far smaller.
pub const MAX_SKETCH_FILE_BYTES: f64 = 2.0 * 1024.0 * 1024.0;
pub use crate::app::page::MAX_PIN_FILE_BYTES;

/// A picked file's name and bytes, or what to tell the user when they were not read (`limit`
/// says how large such a file may be).
fn picked_bytes(file: Picked, limit: &str) -> Result<(String, Vec<u8>), String> {
    let name = file.name;
    match file.bytes {
        Ok(bytes) => Ok((name, bytes)),
        Err(Refused::TooBig(size)) => Err(format!("{name} is {:.1} MB; {limit}", size / 1024.0 / 1024.0)),
        Err(Refused::Unreadable(why)) => Err(format!("{name} could not be read: {why}")),
    }
}

/// The sketch in a picked file, or what to tell the user.
pub fn sketch_from_file(file: Picked) -> Result<Sketch, String> {
    let (name, bytes) = picked_bytes(file, "a sketch PNG (256×256 pixels) is at most 2 MB")?;
    Sketch::read_png(std::io::Cursor::new(bytes)).map_err(|e| format!("{name}: {e}"))
}

/// What the shell needs of the platform it runs on. Everything here only moves bytes.
pub trait Platform: 'static {
    /// The CPU worker's transport.
    type Worker: Port + 'static;
    /// Runs `task` on this thread, later.
    fn spawn(&self, task: Task);
    /// Downloads `url`.
    fn fetch(&self, url: &str) -> Fetching;
    /// The address bar's fragment (with its `#`), empty without one.
    fn fragment(&self) -> String;
    /// Writes `fragment` into the address bar without a reload.
    fn set_fragment(&self, fragment: &str);
    /// The page's address without its fragment.
    fn address(&self) -> String;
    /// A note for the developer's console.
    fn warn(&self, note: &str);
    /// Offers `bytes` as a download named `name`.
    fn download(&self, name: &str, bytes: &[u8], mime: &str) -> Result<(), String>;
    /// Asks the user for a file of type `accept` (e.g. `image/png`); it lands in `slot`,
    /// unread when it is larger than `max_bytes`.
    fn pick_file(&self, accept: &str, max_bytes: f64, slot: FileSlot) -> Result<(), String>;
    /// Reads a file the user dropped on the page; it is pushed onto `landed`, unread when it
    /// is larger than `max_bytes`.
    fn read_dropped(&self, file: egui::DroppedFileHandle, max_bytes: f64, landed: Rc<RefCell<Vec<Picked>>>);
}

/// The GPU a frame draws the 3-D view with.
pub struct ViewGpu<'a> {
    /// The device.
    pub device: &'a wgpu::Device,
    /// Its queue.
    pub queue: &'a wgpu::Queue,
    /// Its adapter (what it allows decides how the view's target is encoded).
    pub adapter: &'a wgpu::Adapter,
    /// Shows `view` as an egui texture: registers it (`None`) or points the given one at it.
    pub show: &'a mut dyn FnMut(&wgpu::TextureView, Option<egui::TextureId>) -> egui::TextureId,
}

/// What the page's test hooks read (the browser console's and the end-to-end test's).
#[derive(Default)]
pub struct Probes {
    /// The latest frame statistics as JSON.
    pub stats_json: String,
    /// The intervals between drawn frames since the hook last took them (ms), oldest first.
    pub frame_intervals: Vec<f64>,
    /// The tile asked for and its heights (metres) once the world has it.
    pub tile: (Option<TileCoord>, Option<Vec<f32>>),
    /// Where the TEM runs now (target, its name, the world epoch), once it is loaded.
    pub tem: Option<(Target, String, u64)>,
    /// No frame runs while set (a test times CPU work without the rasteriser beside it).
    pub paused: bool,
    /// The context of the latest frame, to wake when the pause ends.
    pub wake: Option<egui::Context>,
}

impl Probes {
    /// Pauses the page's frames (`true`) or resumes them.
    pub fn set_paused(&mut self, paused: bool) {
        self.paused = paused;
        if !paused && let Some(ctx) = &self.wake {
            ctx.request_repaint();
        }
    }
}

/// Most frame intervals kept for the hooks (over half an hour at 60 fps).
const MAX_FRAME_INTERVALS: usize = 120_000;

/// The page: its core, runners, interface and renderer, on a platform.
pub struct PageShell<P: Platform> {
    /// The core.
    pub core: PageCore,
    platform: Rc<P>,
    runners: Rc<Runners<P::Worker>>,
    ui: PageUi,
    renderer: Option<TerrainRenderer>,
    env: Environment,
    /// What the hooks read.
    pub probes: Rc<RefCell<Probes>>,
    /// How many times the page replaced a lost GPU device.
    pub device_restarts: u32,
    clock: web_time::Instant,
    /// What came back from fetches and runners since the last frame.
    inbox: Rc<RefCell<Vec<Delivery>>>,
    texture: Option<egui::TextureId>,
    last_frame_ms: Option<f64>,
    /// Draws a frame of the 3-D view only once the GPU has finished the previous one.
    pacer: crate::render::FramePacer,
    /// What the 3-D view's last drawn frame showed (a software adapter draws a view again
    /// only once it changed).
    drawn_scene: Option<crate::render::pacing::SceneKey>,
    /// The newest frame whose GPU work is done (set by the queue's callback).
    gpu_done: Arc<AtomicU64>,
    /// The main thread's work per frame over the last 120 frames: total, tiles, nodes and
    /// drawing ms, the upload and submit parts of the drawing (ms), and the meshes uploaded.
    frame_work: VecDeque<[f64; 7]>,
    /// Times "Copy link" found the sketch too detailed for a link and sent it as a file.
    link_too_long: u32,
    /// A sketch PNG the user opened, once it is read.
    import: FileSlot,
    /// Where a GeoTIFF to pin lands.
    pin_file: FileSlot,
    /// Where a world bundle to open lands.
    world_file: FileSlot,
    /// Files dropped on the page, once read.
    dropped: Rc<RefCell<Vec<Picked>>>,
}

/// Asks for one more frame. egui answers `request_repaint()` with two; a non-zero delay asks
/// for exactly one, at the next animation frame.
fn repaint_once(ctx: &egui::Context) {
    ctx.request_repaint_after(std::time::Duration::from_micros(1));
}

impl<P: Platform> PageShell<P> {
    /// The page for `core` on `platform`, with its runners, opened at `share`.
    fn new(core: PageCore, platform: Rc<P>, runners: Rc<Runners<P::Worker>>, share: ShareState, env: Environment) -> Self {
        Self {
            core,
            platform,
            runners,
            ui: PageUi::new(share),
            renderer: None,
            env,
            probes: Rc::default(),
            device_restarts: 0,
            clock: web_time::Instant::now(),
            inbox: Rc::default(),
            texture: None,
            last_frame_ms: None,
            pacer: Default::default(),
            drawn_scene: None,
            gpu_done: Arc::default(),
            frame_work: VecDeque::new(),
            link_too_long: 0,
            import: Rc::default(),
            pin_file: Rc::default(),
            world_file: Rc::default(),
            dropped: Rc::default(),
        }
    }

    /// The page as it starts on `platform`: burn on the GPU (or why not), the adapter's name
    /// and whether it is a software rasteriser, the CPU worker (or why there is none), the
    /// page's query (`?tem=`) and, after a lost device, the view to keep and a note.
    pub fn start(
        platform: Rc<P>,
        burn: Result<(burn::tensor::Device, String), String>,
        adapter: (String, bool),
        worker: Result<Rc<P::Worker>, String>,
        query: &str,
        restart: Option<Kept>,
    ) -> Self {
        let (options, notice) = crate::share::PageOptions::from_query(query);
        if let Err(e) = &worker {
            platform.warn(&format!("CPU worker unavailable ({e}); the CPU models run on the main thread"));
        }
        let start = PageStart {
            tem: options.tem,
            world: options.world,
            gpu: burn.as_ref().map(|_| ()).map_err(Clone::clone),
            software_adapter: adapter.1,
            worker: worker.as_ref().map(|_| ()).map_err(Clone::clone),
            status: burn.as_ref().map(|b| b.1.clone()).unwrap_or_default(),
        };
        let runners = Rc::new(Runners::new(worker.ok(), burn.ok().map(|b| crate::jobs::gpu::GpuRunner::new(b.0))));
        let env = Environment { adapter: adapter.0, software_adapter: adapter.1, ..Default::default() };
        Self::open(platform, runners, start, restart, notice, env)
    }

    /// The page's runners.
    pub fn runners(&self) -> &Rc<Runners<P::Worker>> {
        &self.runners
    }

    /// The page on `platform` as it opens: at the view of the address bar's fragment, or at
    /// `restart`'s view (with its note) after a lost device, with what the platform found at
    /// start-up and a notice about the page's options, if any.
    pub fn open(platform: Rc<P>, runners: Rc<Runners<P::Worker>>, start: PageStart, restart: Option<Kept>, notice: Option<String>, env: Environment) -> Self {
        let fragment = platform.fragment();
        let (share, message) = PageCore::opening_view(restart.as_ref().map(|k| (k.share.clone(), k.note.clone())), &fragment, notice);
        let mut core = PageCore::new(share.clone(), start).opened_at(fragment);
        core.message = core.message.take().or(message);
        if let Some((name, pins)) = restart.and_then(|k| k.pinned) {
            core.restore_pins(name, pins);
        }
        Self::new(core, platform, runners, share, env)
    }

    /// The page clock (ms since the shell started).
    fn now_ms(&self) -> f64 {
        self.clock.elapsed().as_secs_f64() * 1e3
    }

    /// Hands the core what came back (and a worker that died meanwhile).
    fn deliver(&mut self) {
        if let Some(why) = self.runners.worker.as_ref().and_then(|w| w.gone())
            && self.core.worker().is_ok()
        {
            self.core.deliver(Delivery::WorkerGone { id: 0, why });
        }
        for d in std::mem::take(&mut *self.inbox.borrow_mut()) {
            self.core.deliver(d);
        }
    }

    /// Carries out what the core asks: each fetch and request becomes a task whose result
    /// lands in the inbox.
    fn carry_out(&mut self) {
        for note in self.core.console.drain(..) {
            self.platform.warn(&note);
        }
        for e in self.core.take_effects() {
            let (inbox, runners, platform) = (self.inbox.clone(), self.runners.clone(), self.platform.clone());
            self.platform.spawn(Box::pin(async move {
                let d = match e {
                    Effect::Fetch { id, url } => Delivery::Fetched { id, bytes: platform.fetch(&url).await },
                    Effect::Post { target, envelope } => runners.call(target, envelope).await,
                };
                inbox.borrow_mut().push(d);
            }));
        }
        let tem = self.core.loads.tem.is_ready().then(|| (self.core.tem_target(), self.core.tem_backend(), self.core.app.epoch()));
        self.probes.borrow_mut().tem = tem;
    }

    /// The sketch panel's files: a download, a file to pick, a picked file that arrived.
    fn sketch_files(&mut self, asks: BrowserAsks) {
        if asks.export_sketch
            && let Err(e) = self.download_sketch(self.core.app.canvas.sketch())
        {
            self.core.message = Some(format!("The sketch could not be exported: {e}"));
        }
        if asks.import_sketch
            && let Err(e) = self.platform.pick_file("image/png", MAX_SKETCH_FILE_BYTES, self.import.clone())
        {
            self.core.message = Some(format!("No file dialog: {e}"));
        }
        let picked = self.import.borrow_mut().take();
        match picked.map(sketch_from_file) {
            Some(Ok(s)) => self.core.app.canvas.load(s),
            Some(Err(e)) => self.core.message = Some(e),
            None => {}
        }
    }

    /// Your terrain: a file to pick, and one picked, opened by the core as a dropped file is
    /// (a GeoTIFF is pinned, a heightmap PNG waits for its answers, a sidecar gives them).
    fn pin_files(&mut self, asks: BrowserAsks) {
        if asks.pin_dem
            && let Err(e) = self.platform.pick_file(".tif,.tiff,.png,.json,image/tiff,image/png", MAX_PIN_FILE_BYTES, self.pin_file.clone())
        {
            self.core.message = Some(format!("No file dialog: {e}"));
        }
        let Some(file) = self.pin_file.borrow_mut().take() else { return };
        let said = picked_bytes(file, "terrain to pin is at most 65 MB (4096² float32 samples)").and_then(|(name, bytes)| self.core.open_file(&name, bytes));
        self.core.message = Some(said.unwrap_or_else(|e| e));
    }

    /// Your world as a file: the bundle to save, one to pick, one picked or dropped (with any
    /// other file dropped on the page: a GeoTIFF to pin, a sketch PNG), opened by the core.
    fn world_files(&mut self, ctx: &egui::Context, asks: BrowserAsks) {
        use crate::share::bundle;
        if asks.save_world {
            let saved = match self.core.save_world() {
                Some(bytes) => {
                    self.platform.download(bundle::FILE_NAME, &bytes, "application/gzip").map(|_| format!("Saved {}: the link and your pinned terrain.", bundle::FILE_NAME))
                }
                None => Err("Nothing is pinned: the link alone is this world.".to_string()),
            };
            self.core.message = Some(saved.unwrap_or_else(|e| e));
        }
        if asks.open_world
            && let Err(e) = self.platform.pick_file(".gz,application/gzip", bundle::MAX_FILE_BYTES, self.world_file.clone())
        {
            self.core.message = Some(format!("No file dialog: {e}"));
        }
        for file in ctx.input(|i| i.raw.dropped_files.clone()) {
            // A world bundle is the largest file a drop may be; PageCore::open_file holds
            // terrain to pin to MAX_PIN_FILE_BYTES.
            self.platform.read_dropped(file, bundle::MAX_FILE_BYTES, self.dropped.clone());
        }
        let mut files: Vec<(Picked, &str)> = std::mem::take(&mut *self.dropped.borrow_mut()).into_iter().map(|f| (f, "a file dropped on the page is at most 192 MB")).collect();
        files.extend(self.world_file.borrow_mut().take().map(|f| (f, "a world bundle is at most 192 MB")));
        for (file, limit) in files {
            let said = picked_bytes(file, limit).and_then(|(name, bytes)| self.core.open_file(&name, bytes));
            self.core.message = Some(said.unwrap_or_else(|e| e));
            self.ui.overlay.reset(self.core.app.settings().clone());
        }
    }

    /// Offers `sketch` as `sketch.png` in the format's palette.
    fn download_sketch(&self, sketch: &Sketch) -> Result<(), String> {
        let mut png = Vec::new();
        sketch.write_png(&mut png).map_err(|e| e.to_string())?;
        self.platform.download("sketch.png", &png, "image/png")
    }

    /// Downloads the terrain around the eye as `ask` says (a PNG's or RAW's sidecar too): the
    /// 32 m tiles, or the learned detail of a TEM level where it is refined, resampled to
    /// 2ⁿ+1 on request; named after the world, seed and spacing. What cannot be made is said in
    /// the message.
    pub fn export(&mut self, ask: crate::ui::ExportAsk) {
        use crate::dem::formats::Format;
        let hf = match ask.level {
            None => self.core.app.export_view().ok_or_else(|| "Nothing to export yet: the tile under the eye is still being made.".to_string()),
            Some(level) => self.core.app.export_refined(level),
        };
        let hf = match hf {
            Ok(hf) if ask.pow2_plus_1 => hf.to_pow2_plus_1(),
            Ok(hf) => hf,
            Err(e) => {
                self.core.message = Some(e);
                return;
            }
        };
        let format = ask.format;
        let (ext, mime) = match format {
            Format::Png16 => ("png", "image/png"),
            Format::Raw16 => ("raw", "application/octet-stream"),
            Format::GeoTiff => ("tif", "image/tiff"),
            Format::Glb => ("glb", "model/gltf-binary"),
        };
        let name = format!("terrain-{}-{}-{}m.{ext}", self.core.app.source().key(), self.core.app.settings().seed, hf.spacing_m);
        let done = hf.export(format, &name).map_err(|e| e.to_string()).and_then(|out| {
            self.platform.download(&name, &out.bytes, mime)?;
            match out.sidecar {
                Some(side) => self.platform.download(&format!("{name}.json"), serde_json::to_string_pretty(&side).unwrap_or_default().as_bytes(), "application/json"),
                None => Ok(()),
            }
        });
        if let Err(e) = done {
            self.core.message = Some(format!("The terrain could not be exported: {e}"));
        }
    }

    /// Keeps the address bar's fragment current (`force`: now), so copying it shares the view.
    fn write_link(&mut self, now: f64, force: bool) {
        if let Some(frag) = self.core.link_to_write(now, force) {
            self.platform.set_fragment(&frag);
        }
    }

    /// "Copy link": the address with the view; a sketch too detailed for a link goes as a file.
    fn copy_link(&mut self, ctx: &egui::Context, now: f64) {
        self.write_link(now, true);
        let (text, file) = self.core.copy_link(&self.platform.address());
        ctx.copy_text(text);
        if let Some(sketch) = file {
            self.link_too_long += 1;
            if let Err(e) = self.download_sketch(&sketch) {
                self.core.message = Some(format!("The sketch could not be downloaded ({e}): use Export PNG in the sketch panel."));
            }
        }
        self.ui.copied_at_ms = Some(now);
    }

    /// Moves the camera and draws the 3-D view into the panel (when there is a GPU and it has
    /// finished the previous frame). Returns whether the view was still: unchanged on a
    /// software adapter, so nothing was drawn.
    fn view(&mut self, ui: &mut egui::Ui, gpu: Option<ViewGpu<'_>>, dt_ms: f64, now: f64, cpu_start: f64) -> bool {
        let ctx = ui.ctx().clone();
        let rect = ui.max_rect();
        let resp = ui.allocate_rect(rect, egui::Sense::click_and_drag());
        let size = crate::render::view_size([rect.width(), rect.height()], ctx.pixels_per_point(), self.env.software_adapter, self.core.app.settings().render_scale);
        self.env.view_px = size;
        self.env.screen_px = [rect.width(), rect.height()].map(|p| (p * ctx.pixels_per_point()).round().max(1.0) as u32);
        let input = crate::ui::control_input(&ctx, &resp);
        let (nodes, params) = self.core.app.frame(&input, dt_ms / 1000.0, size);
        let Some(gpu) = gpu else { return false };
        let clock = self.clock;
        let ms = move || clock.elapsed().as_secs_f64() * 1e3;
        if self.renderer.is_none() {
            self.core.app.set_node_budget(crate::render::node_budget(gpu.device.limits().max_buffer_size));
        }
        let renderer = self.renderer.get_or_insert_with(|| TerrainRenderer::new(gpu.device, crate::render::TargetEncoding::for_adapter(gpu.adapter)));
        if renderer.ensure_target(gpu.device, size) || self.texture.is_none() {
            let view = renderer.color_view().expect("target just ensured");
            self.texture = Some((gpu.show)(view, self.texture));
            self.drawn_scene = None;
        }
        // On a software adapter the picture of an unchanged view is not drawn again: its
        // rasteriser shares the cores with the world's networks (only the water would move).
        let scene = self.env.software_adapter.then(|| crate::render::pacing::SceneKey::of(&nodes, &params));
        let still = scene.is_some() && scene == self.drawn_scene;
        if still {
            self.pacer.skipped();
        } else if self.pacer.may_draw(now) {
            self.drawn_scene = scene;
            let render_start = ms();
            let stats = renderer.render(gpu.device, gpu.queue, &nodes, &params, MESH_KEEP_FRAMES);
            let render_ms = ms() - render_start;
            (self.env.uploads, self.env.triangles, self.env.cpu_ms) = (stats.uploads, stats.triangles, ms() - cpu_start);
            let s = self.core.app.stats();
            self.frame_work.push_back([self.env.cpu_ms, s.world_ms, s.nodes_ms, render_ms, stats.upload_ms, stats.submit_ms, stats.uploads as f64]);
            if self.frame_work.len() > 120 {
                self.frame_work.pop_front();
            }
            let (frame, interval) = self.pacer.drawn(now);
            self.env.views_drawn = frame;
            if let Some(ms) = interval {
                self.core.app.record_frame_time(ms);
                let mut p = self.probes.borrow_mut();
                if p.frame_intervals.len() < MAX_FRAME_INTERVALS {
                    p.frame_intervals.push(ms);
                }
            }
            // The platform paints the overlay (one more submit) after this returns, in the
            // same task; a task asks for "work done" after that paint.
            let (queue, done, ctx) = (gpu.queue.clone(), self.gpu_done.clone(), ctx.clone());
            self.platform.spawn(Box::pin(async move {
                queue.on_submitted_work_done(move || {
                    done.fetch_max(frame, SeqCst);
                    repaint_once(&ctx);
                });
            }));
        }
        if let Some(id) = self.texture {
            ui.painter().image(id, rect, egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)), egui::Color32::WHITE);
        }
        still
    }

    /// One frame of the page in `ui` (the root), drawing the 3-D view with `gpu` where there
    /// is one.
    pub fn frame(&mut self, ui: &mut egui::Ui, gpu: Option<ViewGpu<'_>>) {
        let ctx = ui.ctx().clone();
        if self.probes.borrow().paused {
            self.probes.borrow_mut().wake = Some(ctx);
            return;
        }
        let now = self.now_ms();
        let dt_ms = self.last_frame_ms.map(|t| now - t).unwrap_or(16.0);
        self.last_frame_ms = Some(now);
        self.pacer.gpu_done(self.gpu_done.load(SeqCst));
        if let Some(s) = self.core.follow_link(&self.platform.fragment()) {
            self.ui.overlay.reset(s);
        }
        let cpu_start = self.now_ms();
        self.deliver();
        self.core.start_work(now);
        self.carry_out();
        {
            let mut p = self.probes.borrow_mut();
            if let (Some(c), None) = (p.tile.0, &p.tile.1) {
                p.tile.1 = self.core.app.tile_heights(c).map(<[f32]>::to_vec);
            }
        }
        let still = egui::CentralPanel::no_frame().show(ui, |ui| self.view(ui, gpu, dt_ms, now, cpu_start)).inner;
        self.env.take_core(&self.core);
        let asks = self.ui.show(&ctx, &mut self.core, &self.env, now);
        self.sketch_files(asks);
        self.pin_files(asks);
        self.world_files(&ctx, asks);
        // A stroke goes out in the frame that drew it.
        self.core.start_sketch_jobs();
        self.carry_out();
        if asks.copy_link {
            self.copy_link(&ctx, now);
        }
        if let Some(ask) = asks.export {
            self.export(ask);
        }
        self.write_link(now, false);
        self.probes.borrow_mut().stats_json = self.ui.stats_json(&self.core, &self.env, &self.frame_work, self.device_restarts, self.link_too_long);
        if self.pacer.waiting() {
            // The GPU's "work done" asks for the next frame; this is the fallback.
            ctx.request_repaint_after(std::time::Duration::from_millis(crate::render::pacing::GPU_STALL_MS as u64));
        } else if still {
            // Nothing to draw: look again shortly (input wakes the page at once).
            ctx.request_repaint_after(std::time::Duration::from_millis(crate::render::pacing::STILL_FRAME_MS));
        } else {
            repaint_once(&ctx);
        }
    }
}

#[cfg(test)]
mod tests;
