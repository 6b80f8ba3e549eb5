//! The egui overlay: statistics, progress, settings, camera mode, share-link button and
//! messages. It edits a copy of the settings and reports what the user asked for; the shell
//! applies it.

pub mod page;
pub mod shell;
pub mod sketch;

use crate::app::AppStats;
use crate::app::loads::Load;
use crate::app::page::PageCore;
use crate::render::camera::{CameraMode, ControlInput};
use crate::share::ShareState;
use crate::world::{NoiseKind, SourceKind};

/// What the page tells the overlay besides the app's own numbers.
#[derive(Clone, Debug, Default)]
pub struct Environment {
    /// Graphics backend and adapter, e.g. "WebGPU · SwiftShader".
    pub adapter: String,
    /// Whether the adapter rasterises on the CPU (the 3-D view is then drawn at
    /// [`crate::render::SOFTWARE_VIEW_SCALE`]).
    pub software_adapter: bool,
    /// The 3-D view's target (pixels, [`crate::render::view_size`]).
    pub view_px: [u32; 2],
    /// The screen pixels the 3-D view covers.
    pub screen_px: [u32; 2],
    /// How long the CPU worker rests per ms of work
    /// ([`crate::models::runtime::worker_rest_per_work`]; 0: it works at full speed).
    pub worker_rest_per_work: f64,
    /// State of the neural-network backend (burn), e.g. "burn wgpu ready (3.1 ms self-check)".
    pub ml_status: String,
    /// What the start-up probe measured (`TEM probe: WebGPU 3.1 ms, CPU 41.0 ms a quad`), while
    /// it runs or once it has.
    pub tem_probe: Option<String>,
    /// What the sketch generator's probe measured (`sketch probe: WebGPU … a sketch`).
    pub sketch_probe: Option<String>,
    /// Name of the tile source.
    pub source: String,
    /// TEM weight files loaded / total, while they load.
    pub tem_loading: Option<(usize, usize)>,
    /// Why learned refinement is off, if it failed.
    pub tem_error: Option<String>,
    /// Whether the TEM models are loaded.
    pub tem_ready: bool,
    /// Node meshes uploaded in the last frame.
    pub uploads: usize,
    /// Triangles drawn in the last frame.
    pub triangles: usize,
    /// CPU time of the last frame's streaming, selection and draw encoding (milliseconds).
    pub cpu_ms: f64,
    /// Frames of the 3-D view drawn since the page started (a software adapter does not draw
    /// an unchanged view again, so this can stay behind the page's frames).
    pub views_drawn: u64,
    /// Where the sketch generator runs ("WebGPU" or "CPU worker").
    pub sketch_backend: &'static str,
    /// Where the learned world's networks run ("WebGPU", or "CPU worker" and why).
    pub world_backend: String,
    /// The world networks' probe, if it has something to say.
    pub world_probe: Option<String>,
    /// Milliseconds of network work the GPU ran per learned tile made through it.
    pub world_gpu_ms_per_tile: Option<f64>,
    /// Items of the world's network work in each of the GPU's calls now, where they run there.
    pub world_gpu_call_items: Option<usize>,
    /// Whether those calls run a ×4 window in two halves, a frame between them.
    pub world_gpu_call_halves: bool,
    /// Your terrain pinned into the learned world: its file's name and tiles.
    pub pinned: Option<(String, usize)>,
}

impl Environment {
    /// Takes over what the page's core says about its models: the GPU runtime line, the
    /// TEM's progress, error and readiness, where strokes become terrain, the worker's rest.
    pub fn take_core(&mut self, core: &PageCore) {
        self.ml_status = core.status.clone();
        self.tem_probe = core.probe().label("TEM", "quad");
        self.sketch_probe = core.sketch_probe().label("sketch", "sketch");
        self.tem_loading = match core.loads.tem {
            Load::Fetching { done, total } => Some((done, total)),
            _ => None,
        };
        self.tem_error = match &core.loads.tem {
            Load::Failed(why) => Some(why.clone()),
            _ => None,
        };
        self.tem_ready = core.loads.tem.is_ready();
        self.sketch_backend = core.sketch_backend();
        self.world_backend = core.world_backend();
        self.world_probe = core.world_probe().label("world networks", &crate::app::page::world_probe_unit());
        self.world_gpu_ms_per_tile = core.world_gpu_ms_per_tile();
        self.world_gpu_call_items = core.world_on_gpu().then(|| core.gpu_call_items());
        self.world_gpu_call_halves = core.world_on_gpu() && core.gpu_call_halves();
        self.worker_rest_per_work = core.rest_per_work();
        self.source = core.app.source_name();
        self.pinned = core.pinned.clone();
    }
}

/// The overlay's name of the adapter the page draws with through `api` ("WebGPU", "WebGL2")
/// and whether it rasterises on the CPU: the browser's own description (WebGPU's
/// `adapter.info`'s vendor, architecture and description, joined, and its
/// `isFallbackAdapter`) where it gives one, else the first of wgpu's names for it (name,
/// driver, driver info) that is not empty. SwiftShader and llvmpipe are software rasterisers
/// whatever the browser says.
pub fn adapter_name(api: &str, wgpu_names: [&str; 3], browser: Option<(String, bool)>) -> (String, bool) {
    let label = wgpu_names.into_iter().find(|s| !s.is_empty()).unwrap_or("browser adapter");
    let (text, fallback) = browser.unwrap_or_default();
    let shown = if text.is_empty() { label } else { &text };
    let lower = shown.to_ascii_lowercase();
    let software = fallback || lower.contains("swiftshader") || lower.contains("llvmpipe");
    (format!("{api} · {shown}"), software)
}

/// Smallest side (points, which are CSS pixels) of a control on a touch screen: the 44 pt
/// Apple's and the web's accessibility guidelines give for a finger.
pub const TOUCH_TARGET_PT: f32 = 44.0;

/// A small button, or on a touch screen ([`touch_screen`]) one a finger can hit.
pub fn compact_button(ui: &mut egui::Ui, text: impl Into<egui::WidgetText>) -> egui::Response {
    if touch_screen(ui.ctx()) { ui.button(text) } else { ui.small_button(text) }
}

/// Whether [`set_up`] set `ctx` up for a touch screen (its controls [`TOUCH_TARGET_PT`] high).
pub fn touch_screen(ctx: &egui::Context) -> bool {
    ctx.global_style().spacing.interact_size.y >= TOUCH_TARGET_PT
}

/// Sets up the page's egui context: a press and release that do not move apart are a click
/// however long the button is held. egui's default (0.8 s) is measured between the frames that
/// saw the press and the release, so on a page drawing a frame every second or two (software
/// WebGPU, a slow phone) a quick click became a long press and was lost. On a `touch` screen
/// (a coarse pointer) every control is at least [`TOUCH_TARGET_PT`] high (the overlay then
/// opens its panel with a button of that size, [`touch_screen`]).
pub fn set_up(ctx: &egui::Context, touch: bool) {
    ctx.options_mut(|o| o.input_options.max_click_duration = f64::INFINITY);
    if touch {
        ctx.all_styles_mut(|s| s.spacing.interact_size.y = s.spacing.interact_size.y.max(TOUCH_TARGET_PT));
    }
}

/// The camera input of this frame from egui's pointer, touch and keys over the 3-D view's
/// response `resp`: two-finger drag moves and pinch zooms, a drag looks, the wheel scrolls,
/// WASD/arrows/QE/PageUp/PageDown move (unless a text field has the keyboard), Shift boosts.
pub fn control_input(ctx: &egui::Context, resp: &egui::Response) -> ControlInput {
    let mut input = ControlInput { pinch: 1.0, ..Default::default() };
    if let Some(m) = ctx.multi_touch().filter(|m| m.num_touches >= 2) {
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

/// The page's statistics as JSON (read by the end-to-end test and usable from the browser
/// console): the app's numbers, what the overlay shows, the message and link, and where the
/// sketch panel's canvas and buttons are on screen (CSS pixels: x, y, width, height).
/// `frame_work` holds [total, tiles, nodes, drawing, uploads, encoding + submit] ms and the
/// meshes uploaded of recent frames; the worst frame's is reported.
pub fn stats_json(
    core: &PageCore,
    env: &Environment,
    panel: &sketch::SketchPanel,
    overlay: &Overlay,
    frame_work: &std::collections::VecDeque<[f64; 7]>,
    device_restarts: u32,
    link_too_long: u32,
) -> String {
    let rect = |r: egui::Rect| [r.min.x, r.min.y, r.width(), r.height()];
    let app = &core.app;
    let sketch = app.source() == SourceKind::Sketch;
    serde_json::json!({
        "stats": app.stats(), "adapter": env.adapter, "ml_status": env.ml_status, "tem_probe": env.tem_probe, "sketch_probe": env.sketch_probe, "tem_ready": env.tem_ready,
        "tem_error": env.tem_error, "source": env.source, "uploads": env.uploads, "triangles": env.triangles, "cpu_ms": env.cpu_ms,
        "cpu_ms_worst": frame_work.iter().copied().max_by(|a, b| a[0].total_cmp(&b[0])),
        "message": core.message, "device_restarts": device_restarts, "link": app.share_state().to_fragment(),
        "mode": format!("{:?}", app.controller.mode), "sketch_canvas": panel.canvas_rect.filter(|_| sketch).map(rect),
        "sketch_models": format!("{:?}", app.sketch_models()), "sketch_backend": env.sketch_backend,
        "world_backend": env.world_backend, "world_probe": env.world_probe, "world_gpu_ms_per_tile": env.world_gpu_ms_per_tile,
        "world_gpu_call_items": env.world_gpu_call_items, "world_gpu_call_halves": env.world_gpu_call_halves,
        "sketch_variants": panel.variant_count(), "sketch_blends": core.blends, "sketch_blend_chosen": panel.blend_pair().is_some(), "link_too_long": link_too_long,
        "copy_link_button": overlay.buttons.get("copy_link").copied().map(rect), "software_adapter": env.software_adapter, "views_drawn": env.views_drawn, "view_px": env.view_px, "screen_px": env.screen_px,
        "panel": overlay.panel.map(rect), "statistics_shown": overlay.show_stats, "settings_shown": overlay.show_settings,
        "overlay_buttons": overlay.buttons.iter().map(|(k, r)| (*k, rect(*r))).collect::<std::collections::BTreeMap<_, _>>(),
        "worker_rest_per_work": env.worker_rest_per_work,
        "sketch_buttons": panel.buttons.iter().map(|(k, r)| (k.clone(), rect(*r))).collect::<std::collections::BTreeMap<_, _>>(),
    })
    .to_string()
}

/// What the user asked for this frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct UiActions {
    /// New settings to apply (camera pose untouched).
    pub settings: Option<ShareState>,
    /// Copy the share link to the clipboard.
    pub copy_link: bool,
    /// Switch camera mode.
    pub mode: Option<CameraMode>,
    /// Close the message banner.
    pub dismiss_message: bool,
    /// Download the terrain around the eye.
    pub export: Option<ExportAsk>,
    /// Pick a GeoTIFF to pin into the learned world.
    pub pin_dem: bool,
    /// Take the pinned terrain out of the learned world.
    pub unpin: bool,
    /// Download the world (its link and pinned terrain) as a bundle.
    pub save_world: bool,
    /// Pick a world bundle to open.
    pub open_world: bool,
}

/// An export the user asked for: the format, the spacing (`level`: a TEM level where refined,
/// `None` for the 32 m tiles) and whether to resample to a 2ⁿ+1 square.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ExportAsk {
    /// The file format.
    pub format: crate::dem::formats::Format,
    /// TEM level (0 = 16 m … 4 = 1 m), or `None` for 32 m.
    pub level: Option<usize>,
    /// Resample to 2ⁿ+1 samples a side (Unity, Unreal).
    pub pow2_plus_1: bool,
}

/// Overlay state that lives between frames.
#[derive(Clone, Debug)]
pub struct Overlay {
    /// Settings being edited.
    pub draft: ShareState,
    /// The settings last handed to the app.
    applied: ShareState,
    /// Whether the settings section is open.
    pub show_settings: bool,
    /// The statistics are shown (off by default: the overlay is for people).
    pub show_stats: bool,
    /// Where the overlay's controls were drawn last frame (points), for tests that click
    /// them: `copy_link`, `settings`, `statistics`, `pin_dem`, and while the settings are open `seed`,
    /// `world_tcm`, `world_procedural`, `world_sketch`.
    pub buttons: std::collections::BTreeMap<&'static str, egui::Rect>,
    /// The export's spacing: a TEM level, or `None` for 32 m.
    pub export_level: Option<usize>,
    /// Exports are resampled to 2ⁿ+1 samples a side.
    pub export_pow2: bool,
    /// Where the panel ("Terrain") was drawn last frame (points), open or collapsed.
    pub panel: Option<egui::Rect>,
    /// On a touch screen, whether the panel is open (it starts so unless the screen is
    /// compact); elsewhere egui's window keeps that state.
    touch_panel_open: Option<bool>,
}

/// Below this width or height (points, which are CSS pixels) the panel starts collapsed to its
/// title bar, so that the terrain fills a phone's screen (390 × 844 portrait, 844 × 390
/// landscape); its ▶, or a double tap on the title, opens it.
pub const COMPACT_SCREEN_PT: [f32; 2] = [600.0, 480.0];

/// Whether a screen of `size` points is too small for the open panel ([`COMPACT_SCREEN_PT`]).
pub fn compact_screen(size: egui::Vec2) -> bool {
    size.x < COMPACT_SCREEN_PT[0] || size.y < COMPACT_SCREEN_PT[1]
}

impl Overlay {
    /// An overlay editing `s`.
    pub fn new(s: ShareState) -> Self {
        Self {
            draft: s.clone(),
            applied: s,
            show_settings: false,
            show_stats: false,
            buttons: Default::default(),
            export_level: None,
            export_pow2: false,
            panel: None,
            touch_panel_open: None,
        }
    }

    /// Replaces the draft with settings that came from elsewhere (e.g. a link opened in the
    /// same page).
    pub fn reset(&mut self, s: ShareState) {
        *self = Self { show_settings: self.show_settings, export_level: self.export_level, export_pow2: self.export_pow2, ..Self::new(s) };
    }

    /// Draws the overlay. `speed_mps`, `show_lod` and `refine` (learned detail on/off) are
    /// edited in place.
    #[allow(clippy::too_many_arguments)]
    pub fn show(
        &mut self,
        ctx: &egui::Context,
        stats: &AppStats,
        env: &Environment,
        mode: CameraMode,
        speed_mps: &mut f64,
        show_lod: &mut bool,
        refine: &mut bool,
        message: Option<&str>,
        link_copied: bool,
    ) -> UiActions {
        let mut act = UiActions::default();
        self.buttons.clear();
        if let Some(msg) = message {
            egui::Window::new("Notice").anchor(egui::Align2::CENTER_TOP, [0.0, 8.0]).collapsible(false).resizable(false).title_bar(false).show(ctx, |ui| {
                ui.horizontal(|ui| {
                    ui.label(egui::RichText::new(msg).color(egui::Color32::from_rgb(255, 200, 120)));
                    if ui.button("OK").clicked() {
                        act.dismiss_message = true;
                    }
                });
            });
        }
        let compact = compact_screen(ctx.content_rect().size());
        // On a touch screen the panel opens and closes with a button a finger can hit: egui's
        // own ▶ in the title bar is under 20 pt.
        let touch = touch_screen(ctx);
        let window = egui::Window::new("Terrain").anchor(egui::Align2::LEFT_TOP, [8.0, 8.0]).resizable(false).default_width(260.0);
        let window = if touch { window.title_bar(false) } else { window.default_open(!compact) };
        let panel = window.show(ctx, |ui| {
            if touch {
                let open = *self.touch_panel_open.get_or_insert(!compact);
                let text = if open { "Terrain · close the panel" } else { "Terrain · open the panel" };
                let r = ui.add(egui::Button::new(egui::RichText::new(text).strong()).min_size(egui::vec2(4.0 * TOUCH_TARGET_PT, TOUCH_TARGET_PT)));
                self.buttons.insert("panel_toggle", r.rect);
                if r.clicked() {
                    self.touch_panel_open = Some(!open);
                }
                if !open {
                    return;
                }
            }
            // For people: the world, what is being made, the controls. The numbers behind
            // "Statistics" (the tests read them from the statistics JSON either way).
            let seed = if stats.source == SourceKind::Sketch.label() && !env.source.contains("learned") { String::new() } else { format!(" · seed {}", self.applied.seed) };
            ui.label(egui::RichText::new(format!("{}{seed}", env.source)).strong());
            // Always shown, and no spinner: a widget that appears, or a spinner, asks egui for
            // repaints, which would draw the overlay between the paced frames of the 3-D view
            // (render::pacing) and delay the next one.
            let total = stats.tiles_pending + stats.tiles_cached.min(1000);
            // The previous world's note shares the bar's one row: a line that comes and goes
            // would move every control below it under the user's pointer.
            let text = match (stats.tiles_pending > 0, stats.previous_world_shown) {
                (true, true) => format!("making {} tiles · previous world shown meanwhile", stats.tiles_pending),
                (true, false) => format!("making {} tiles of terrain", stats.tiles_pending),
                (false, _) => "every tile in view made".to_string(),
            };
            ui.add(egui::ProgressBar::new(1.0 - stats.tiles_pending as f32 / total.max(1) as f32).text(text));
            if let Some((done, total)) = env.tem_loading {
                ui.add(egui::ProgressBar::new(done as f32 / total.max(1) as f32).text(format!("loading learned detail {done}/{total}")));
            } else if let Some(e) = &env.tem_error {
                ui.label(egui::RichText::new(e).color(egui::Color32::from_rgb(255, 200, 120)));
            } else if env.tem_ready {
                ui.horizontal(|ui| {
                    ui.checkbox(refine, "Learned detail");
                    if stats.refine_backend.is_empty() {
                        ui.label("off");
                    } else {
                        ui.label(format!("on {}", stats.refine_backend));
                    }
                });
            }
            if stats.lod_px_effective > self.applied.lod_px * 1.001 {
                let text = format!("Detail lowered to fit the GPU's memory: LOD target {:.1} px instead of {:.1} px", stats.lod_px_effective, self.applied.lod_px);
                ui.label(egui::RichText::new(text).color(egui::Color32::from_rgb(255, 200, 120)));
            }
            ui.separator();
            ui.horizontal(|ui| {
                let mut m = mode;
                ui.selectable_value(&mut m, CameraMode::Fly, "Fly");
                ui.selectable_value(&mut m, CameraMode::Orbit, "Orbit");
                if m != mode {
                    act.mode = Some(m);
                }
            });
            ui.add(egui::Slider::new(speed_mps, 5.0..=20_000.0).logarithmic(true).text("speed m/s"));
            ui.horizontal(|ui| {
                let copy = ui.button("Copy link");
                self.buttons.insert("copy_link", copy.rect);
                if copy.clicked() {
                    act.copy_link = true;
                }
                let settings = ui.toggle_value(&mut self.show_settings, "Settings");
                let statistics = ui.toggle_value(&mut self.show_stats, "Statistics");
                self.buttons.insert("settings", settings.rect);
                self.buttons.insert("statistics", statistics.rect);
                // Last in the row, so that it moves no button.
                if link_copied {
                    ui.label("copied ✔");
                }
            });
            ui.horizontal(|ui| {
                use crate::dem::formats::Format;
                ui.label("Export");
                for (format, name, what) in [
                    (Format::Png16, "PNG", "16-bit heightmap + a .json of its metres and spacing"),
                    (Format::Raw16, "RAW", "16-bit little-endian heightmap (Unity, Unreal) + a .json of its metres and spacing"),
                    (Format::GeoTiff, "GeoTIFF", "float32 metres, for GIS"),
                    (Format::Glb, "glTF", "a mesh with normals (Blender, Godot)"),
                ] {
                    if compact_button(ui, name).on_hover_text(format!("the terrain around the eye: {what}")).clicked() {
                        act.export = Some(ExportAsk { format, level: self.export_level, pow2_plus_1: self.export_pow2 });
                    }
                }
            });
            ui.horizontal(|ui| {
                ui.label("at");
                let spacing = |l: Option<usize>| l.map_or("32 m (tiles)".to_string(), |l| format!("{} m (learned detail)", crate::models::tem::LEVEL_SPACING_M[l]));
                let combo = egui::ComboBox::from_id_salt("export_spacing").selected_text(spacing(self.export_level)).show_ui(ui, |ui| {
                    for l in std::iter::once(None).chain((0..crate::models::tem::LEVELS).map(Some)) {
                        ui.selectable_value(&mut self.export_level, l, spacing(l));
                    }
                });
                self.buttons.insert("export_spacing", combo.response.rect);
                ui.checkbox(&mut self.export_pow2, "2ⁿ+1").on_hover_text("resampled to a square of 2ⁿ+1 samples a side, as Unity and Unreal terrains want");
            });
            // Rows that never wrap: a wrapped row's buttons would move as the overlay's width
            // follows a progress note.
            ui.horizontal(|ui| {
                ui.label("Your terrain");
                let pin = compact_button(ui, "Pin terrain…").on_hover_text(
                    "a DEM placed where you are in the learned world, which grows around it: a GeoTIFF stating its pixel size (32 m or finer), or a heightmap PNG (16/8-bit grey or terrain-RGB; its spacing and heights are asked)",
                );
                self.buttons.insert("pin_dem", pin.rect);
                if pin.clicked() {
                    act.pin_dem = true;
                }
                let open = compact_button(ui, "Open world…")
                    .on_hover_text("a world bundle saved with \"Save world\": its link and pinned terrain (or drop it, a GeoTIFF or a sketch PNG on the page)");
                self.buttons.insert("open_world", open.rect);
                if open.clicked() {
                    act.open_world = true;
                }
            });
            if let Some((name, tiles)) = &env.pinned {
                ui.horizontal(|ui| {
                    let unpin = compact_button(ui, "Unpin").on_hover_text(format!("{name} ({tiles} tiles) is pinned: take it out and make the world again without it"));
                    self.buttons.insert("unpin", unpin.rect);
                    if unpin.clicked() {
                        act.unpin = true;
                    }
                    let save =
                        compact_button(ui, "Save world").on_hover_text("a file with the link and your pinned terrain, which a link cannot carry: whoever opens it sees this world");
                    self.buttons.insert("save_world", save.rect);
                    if save.clicked() {
                        act.save_world = true;
                    }
                    ui.label(egui::RichText::new(format!("{name} · {tiles} tiles")).small());
                });
            }
            if self.show_settings
                && let Some(s) = self.settings_ui(ui)
            {
                act.settings = Some(s);
            }
            if self.show_stats {
                ui.separator();
                Self::statistics(ui, stats, env, show_lod);
            }
            egui::CollapsingHeader::new("Controls").default_open(true).show(ui, |ui| {
                ui.label("Drag: look · WASD: move · Q/E: down/up · Shift: faster · wheel: speed (fly) or zoom (orbit)");
                ui.label("Touch: drag to look · two fingers to move · pinch to fly forward/zoom");
            });
        });
        self.panel = panel.map(|p| p.response.rect);
        act
    }

    /// The numbers behind the view: frame times, tiles, nodes, triangles, the eye, the GPU and
    /// where each model runs.
    fn statistics(ui: &mut egui::Ui, stats: &AppStats, env: &Environment, show_lod: &mut bool) {
        let fps = if stats.frame_ms_median > 0.0 { 1000.0 / stats.frame_ms_median } else { 0.0 };
        ui.monospace(format!("{fps:5.1} FPS   {:5.1} ms (worst {:.1})", stats.frame_ms_median, stats.frame_ms_worst));
        ui.monospace(format!("tiles {} generated, {}/{} cached", stats.tiles_generated, stats.tiles_cached, stats.tiles_capacity));
        ui.monospace(format!("{:.2} ms per tile   {} evicted", stats.ms_per_tile, stats.tiles_evicted));
        ui.monospace(format!("nodes {} drawn (depth ≤ {}), {} cached", stats.nodes_drawn, stats.max_depth_drawn, stats.nodes_cached));
        ui.monospace(format!("{} k triangles, {} uploads, CPU {:.1} ms", env.triangles / 1000, env.uploads, env.cpu_ms));
        ui.monospace(format!("eye {:.0}, {:.0}, {:.0} m", stats.eye_m[0], stats.eye_m[1], stats.eye_m[2]));
        ui.label(format!("GPU: {}", env.adapter));
        let share = env.view_px[0] as f64 / env.screen_px[0].max(1) as f64;
        let software = if env.software_adapter { " (software GPU)" } else { "" };
        ui.label(format!("3-D view {}×{} px, {:.0} % of the screen's resolution{software}", env.view_px[0], env.view_px[1], share * 100.0));
        if env.software_adapter && env.worker_rest_per_work > 0.0 {
            ui.label(format!("CPU worker at 1/{:.0} of a core while flying (smooth frames)", 1.0 + env.worker_rest_per_work));
        }
        ui.label(format!("ML: {}", env.ml_status));
        for probe in [&env.tem_probe, &env.sketch_probe, &env.world_probe].into_iter().flatten() {
            ui.label(probe);
        }
        if stats.source == SourceKind::Sketch.label() && stats.sketch_shown > 0 {
            ui.monospace(format!("sketch → terrain {:.0} ms on {}", stats.sketch_ms, env.sketch_backend));
        }
        if stats.source == SourceKind::Learned.label() {
            ui.monospace(format!(
                "tile queue {} waiting, {} in flight, {:.0} ms/tile",
                stats.tiles_pending.saturating_sub(stats.tile_jobs.in_flight),
                stats.tile_jobs.in_flight,
                stats.ms_per_tile
            ));
            let gpu_ms = env.world_gpu_ms_per_tile.map(|ms| format!(", {ms:.0} ms/tile there")).unwrap_or_default();
            let halves = if env.world_gpu_call_halves { " in halves" } else { "" };
            let items = env.world_gpu_call_items.map(|k| format!(", {k} a call{halves}")).unwrap_or_default();
            ui.monospace(format!("world networks on {}{gpu_ms}{items}", env.world_backend));
        }
        if env.tem_ready {
            let depth_m = crate::world::TILE_SIZE_M / f64::from(1u32 << stats.max_depth_drawn) / crate::world::quadtree::NODE_QUADS as f64;
            ui.monospace(format!("depth {} ({depth_m} m)  {:.1} ms/quad  {} quads", stats.max_depth_drawn, stats.ms_per_quad, stats.quads_made));
        }
        ui.checkbox(show_lod, "LOD colours");
    }

    fn settings_ui(&mut self, ui: &mut egui::Ui) -> Option<ShareState> {
        use crate::world::noise::ranges;
        let d = &mut self.draft;
        egui::Grid::new("settings").num_columns(2).show(ui, |ui| {
            ui.label("Seed");
            // A typed seed applies on Enter or when the field loses focus, not per keystroke
            // (every seed is a new world).
            let seed = ui.add(egui::DragValue::new(&mut d.seed).update_while_editing(false));
            self.buttons.insert("seed", seed.rect);
            ui.end_row();
            ui.label("Radius (tiles)");
            ui.add(egui::Slider::new(&mut d.radius_tiles, crate::share::RADIUS_TILES));
            ui.end_row();
            ui.label("LOD target (px)");
            ui.add(egui::Slider::new(&mut d.lod_px, crate::share::LOD_PX).logarithmic(true));
            ui.end_row();
            ui.label("Shading");
            ui.horizontal(|ui| {
                for (plain, text, name) in [(false, "Full", "shade_full"), (true, "Plain (faster)", "shade_plain")] {
                    let r = ui.selectable_value(&mut d.plain_shading, plain, text);
                    self.buttons.insert(name, r.rect);
                }
            });
            ui.end_row();
            ui.label("Resolution");
            ui.horizontal(|ui| {
                for (scale, text, name) in [(None, "Auto", "scale_auto"), (Some(1.0), "100 %", "scale_100"), (Some(0.75), "75 %", "scale_75"), (Some(0.5), "50 %", "scale_50")] {
                    let r = ui.selectable_value(&mut d.render_scale, scale, text);
                    self.buttons.insert(name, r.rect);
                }
            });
            ui.end_row();
            ui.label("World");
            ui.horizontal(|ui| {
                for (kind, name) in [(SourceKind::Learned, "world_tcm"), (SourceKind::Procedural, "world_procedural"), (SourceKind::Sketch, "world_sketch")] {
                    let r = ui.selectable_value(&mut d.source, kind, kind.label());
                    self.buttons.insert(name, r.rect);
                }
            });
            ui.end_row();
            ui.label("Autopilot (m/s)");
            ui.add(egui::Slider::new(&mut d.autopilot_mps, crate::share::AUTOPILOT_MPS));
            ui.end_row();
            if d.source != SourceKind::Procedural {
                return;
            }
            ui.label("Noise");
            ui.horizontal(|ui| {
                ui.selectable_value(&mut d.noise.kind, NoiseKind::Ridged, "ridged");
                ui.selectable_value(&mut d.noise.kind, NoiseKind::Fbm, "fBm");
            });
            ui.end_row();
            ui.label("Octaves");
            ui.add(egui::Slider::new(&mut d.noise.octaves, ranges::OCTAVES));
            ui.end_row();
            ui.label("Persistence");
            ui.add(egui::Slider::new(&mut d.noise.persistence, ranges::PERSISTENCE));
            ui.end_row();
            ui.label("Lacunarity");
            ui.add(egui::Slider::new(&mut d.noise.lacunarity, ranges::LACUNARITY));
            ui.end_row();
            ui.label("Wavelength (m)");
            ui.add(egui::Slider::new(&mut d.noise.wavelength_m, ranges::WAVELENGTH_M).logarithmic(true));
            ui.end_row();
            ui.label("Amplitude (m)");
            ui.add(egui::Slider::new(&mut d.noise.amplitude_m, ranges::AMPLITUDE_M));
            ui.end_row();
            ui.label("Base (m)");
            ui.add(egui::Slider::new(&mut d.noise.base_m, ranges::BASE_M));
            ui.end_row();
        });
        // Apply once a drag ends (or a value is typed), not on every intermediate value: each
        // change of seed or noise regenerates the world.
        if ui.ctx().egui_is_using_pointer() || self.draft == self.applied {
            return None;
        }
        self.applied = self.draft.clone();
        Some(self.draft.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::NoiseParams;

    /// Draws the overlay for one frame with `events`, returning the settings it applied.
    fn overlay_frame(ctx: &egui::Context, overlay: &mut Overlay, events: Vec<egui::Event>) -> Option<ShareState> {
        overlay_frame_with(ctx, overlay, events, &AppStats::default(), false)
    }

    /// [`overlay_frame`] with the app's `stats` and whether a link was just copied.
    fn overlay_frame_with(ctx: &egui::Context, overlay: &mut Overlay, events: Vec<egui::Event>, stats: &AppStats, link_copied: bool) -> Option<ShareState> {
        overlay_frame_on(ctx, overlay, events, stats, link_copied, egui::vec2(1280.0, 1600.0))
    }

    /// [`overlay_frame_with`] on a screen of `size` points.
    fn overlay_frame_on(ctx: &egui::Context, overlay: &mut Overlay, events: Vec<egui::Event>, stats: &AppStats, link_copied: bool, size: egui::Vec2) -> Option<ShareState> {
        let input = egui::RawInput { screen_rect: Some(egui::Rect::from_min_size(egui::Pos2::ZERO, size)), events, ..Default::default() };
        let (mut speed, mut lod, mut refine) = (100.0, false, true);
        let mut applied = None;
        let out = ctx.run_ui(input, |ui| {
            applied = overlay.show(ui.ctx(), stats, &Environment::default(), CameraMode::Fly, &mut speed, &mut lod, &mut refine, None, link_copied).settings;
        });
        let mut delta = out.textures_delta;
        delta.clear();
        applied
    }

    /// On a phone's screen, 390 × 844 points portrait or 844 × 390 landscape, the panel starts
    /// as its title bar alone (under 40 pt tall, under 5 % of the screen, no button drawn); on
    /// 960 × 600 it starts open, with its buttons.
    #[test]
    fn the_panel_starts_collapsed_on_a_phones_screen_and_open_on_a_laptops() {
        for (size, compact) in [(egui::vec2(390.0, 844.0), true), (egui::vec2(844.0, 390.0), true), (egui::vec2(960.0, 600.0), false)] {
            let ctx = egui::Context::default();
            let mut overlay = Overlay::new(ShareState::default());
            for _ in 0..3 {
                overlay_frame_on(&ctx, &mut overlay, vec![], &AppStats::default(), false, size);
            }
            let panel = overlay.panel.expect("the panel is drawn");
            assert_eq!(compact_screen(size), compact);
            if compact {
                assert!(panel.height() < 40.0 && panel.area() < 0.05 * size.x * size.y, "{size:?}: panel {panel:?}");
                assert!(overlay.buttons.is_empty(), "{size:?}: {:?}", overlay.buttons.keys());
            } else {
                assert!(panel.height() > 200.0 && overlay.buttons.contains_key("copy_link"), "{size:?}: panel {panel:?}");
            }
        }
    }

    /// On a touch screen ([`set_up`] with `touch`) every control of the open panel is at least
    /// 44 pt high; on a phone's screen the panel starts as one 44 pt button, which opens it
    /// when tapped (then "copy link" is drawn) and closes it when tapped again.
    #[test]
    fn on_a_touch_screen_the_panels_controls_are_a_fingers_size_and_its_button_opens_it() {
        let size = egui::vec2(390.0, 844.0);
        let ctx = egui::Context::default();
        set_up(&ctx, true);
        assert!(touch_screen(&ctx));
        let mut overlay = Overlay::new(ShareState::default());
        for _ in 0..3 {
            overlay_frame_on(&ctx, &mut overlay, vec![], &AppStats::default(), false, size);
        }
        let toggle = overlay.buttons["panel_toggle"];
        assert_eq!(overlay.buttons.len(), 1, "{:?}", overlay.buttons.keys());
        assert!(toggle.height() >= TOUCH_TARGET_PT && overlay.panel.unwrap().area() < 0.05 * size.x * size.y, "{toggle:?}");
        let tap = |overlay: &mut Overlay, at: egui::Pos2| {
            let press = |pressed| egui::Event::PointerButton { pos: at, button: egui::PointerButton::Primary, pressed, modifiers: Default::default() };
            overlay_frame_on(&ctx, overlay, vec![egui::Event::PointerMoved(at), press(true)], &AppStats::default(), false, size);
            overlay_frame_on(&ctx, overlay, vec![press(false)], &AppStats::default(), false, size);
            overlay_frame_on(&ctx, overlay, vec![], &AppStats::default(), false, size);
        };
        tap(&mut overlay, toggle.center());
        assert!(overlay.buttons.contains_key("copy_link"), "{:?}", overlay.buttons.keys());
        for (name, r) in &overlay.buttons {
            assert!(r.height() >= TOUCH_TARGET_PT - 0.5, "{name}: {r:?}");
        }
        let toggle = overlay.buttons["panel_toggle"];
        tap(&mut overlay, toggle.center());
        assert_eq!(overlay.buttons.len(), 1, "closed again: {:?}", overlay.buttons.keys());
    }

    /// The overlay's buttons stay where they are (to 0.5 pt) while tiles are being made, the
    /// previous world is shown meanwhile, or "copied" is shown: a note that comes and goes
    /// must not move a button from under the user's pointer.
    #[test]
    fn the_overlay_buttons_do_not_move_with_progress_notes() {
        let ctx = egui::Context::default();
        let mut overlay = Overlay::new(ShareState::default());
        let calm = AppStats::default();
        for _ in 0..3 {
            overlay_frame_with(&ctx, &mut overlay, vec![], &calm, false);
        }
        let before = overlay.buttons.clone();
        assert!(["copy_link", "settings", "statistics"].iter().all(|k| before.contains_key(k)), "{:?}", before.keys());
        let busy = AppStats { tiles_pending: 12, previous_world_shown: true, ..Default::default() };
        for (stats, copied) in [(&busy, false), (&busy, true), (&calm, true)] {
            for _ in 0..3 {
                overlay_frame_with(&ctx, &mut overlay, vec![], stats, copied);
            }
            for (name, rect) in &before {
                let now = overlay.buttons[name];
                assert!(
                    (now.min - rect.min).length() < 0.5,
                    "{name} moved from {rect:?} to {now:?} (pending {}, previous world {}, copied {copied})",
                    stats.tiles_pending,
                    stats.previous_world_shown
                );
            }
        }
    }

    /// A seed typed digit by digit into the settings is applied once, on Enter: no world is
    /// made for "1" or "12" on the way to "123".
    #[test]
    fn a_typed_seed_applies_on_enter_not_per_keystroke() {
        let mut overlay = Overlay::new(ShareState::default());
        overlay.show_settings = true;
        let ctx = egui::Context::default();
        for _ in 0..3 {
            assert_eq!(overlay_frame(&ctx, &mut overlay, vec![]), None);
        }
        let at = overlay.buttons.get("seed").expect("the seed field is shown").center();
        let button = |pressed| egui::Event::PointerButton { pos: at, button: egui::PointerButton::Primary, pressed, modifiers: Default::default() };
        let mut applied = Vec::new();
        applied.extend(overlay_frame(&ctx, &mut overlay, vec![egui::Event::PointerMoved(at), button(true)]));
        applied.extend(overlay_frame(&ctx, &mut overlay, vec![button(false)]));
        applied.extend(overlay_frame(&ctx, &mut overlay, vec![]));
        // The click selected the field's text: the digits replace it.
        for digit in ["1", "2", "3"] {
            applied.extend(overlay_frame(&ctx, &mut overlay, vec![egui::Event::Text(digit.into())]));
        }
        assert!(applied.is_empty(), "applied while typing: {:?}", applied.iter().map(|s| s.seed).collect::<Vec<_>>());
        let enter = egui::Event::Key { key: egui::Key::Enter, physical_key: None, pressed: true, repeat: false, modifiers: Default::default() };
        applied.extend(overlay_frame(&ctx, &mut overlay, vec![enter]));
        applied.extend(overlay_frame(&ctx, &mut overlay, vec![]));
        assert_eq!(applied.iter().map(|s| s.seed).collect::<Vec<_>>(), vec![123], "one world, for the whole seed");
    }

    /// Linked values at both ends of every range a link may carry (radius 1 and 16 tiles, LOD
    /// 0.5 and 64 px, autopilot 0 and 5000 m/s, 1 and 16 octaves, persistence 0 and 1,
    /// lacunarity 1 and 4, wavelength 100 m and 1000 km, amplitude 0 and 20 km, base ±20 km)
    /// survive opening Settings: nothing is clamped and no change is applied.
    #[test]
    fn opening_settings_keeps_every_value_a_link_may_carry() {
        let low = NoiseParams { octaves: 1, persistence: 0.0, lacunarity: 1.0, wavelength_m: 100.0, amplitude_m: 0.0, base_m: -20_000.0, ..Default::default() };
        let high = NoiseParams { octaves: 16, persistence: 1.0, lacunarity: 4.0, wavelength_m: 1.0e6, amplitude_m: 20_000.0, base_m: 20_000.0, ..Default::default() };
        let linked = [
            ShareState { source: SourceKind::Procedural, radius_tiles: 1.0, lod_px: 0.5, autopilot_mps: 0.0, noise: low, ..Default::default() },
            ShareState { source: SourceKind::Procedural, radius_tiles: 16.0, lod_px: 64.0, autopilot_mps: 5000.0, noise: high, ..Default::default() },
            ShareState { source: SourceKind::Procedural, radius_tiles: 5.3, lod_px: 3.3, autopilot_mps: 1234.5, ..Default::default() },
        ];
        for s in linked {
            let s = ShareState::from_fragment(&s.to_fragment()).expect("a link the parser takes");
            let mut overlay = Overlay::new(s.clone());
            overlay.show_settings = true;
            let ctx = egui::Context::default();
            let mut applied = None;
            for _ in 0..3 {
                applied = applied.or(overlay_frame(&ctx, &mut overlay, vec![]));
            }
            assert_eq!(overlay.draft, s, "the settings panel changed a linked value");
            assert_eq!(applied, None);
        }
    }

    /// The browser's description names the adapter and SwiftShader in it marks a software
    /// rasteriser; without one, wgpu's first name stands in, and SwiftShader in it (WebGL2's
    /// unmasked renderer) marks software too; the API comes first.
    #[test]
    fn the_adapter_is_named_by_the_browser_and_swiftshader_is_software() {
        let names = ["", "Some driver", "1.2"];
        assert_eq!(adapter_name("WebGPU", names, Some(("google swiftshader".into(), false))), ("WebGPU · google swiftshader".into(), true));
        assert_eq!(adapter_name("WebGPU", names, Some(("nvidia ampere".into(), false))), ("WebGPU · nvidia ampere".into(), false));
        assert_eq!(adapter_name("WebGPU", names, Some(("".into(), true))), ("WebGPU · Some driver".into(), true));
        assert_eq!(adapter_name("WebGPU", names, None), ("WebGPU · Some driver".into(), false));
        let angle = "ANGLE (Google, Vulkan 1.3.0 (SwiftShader Device (Subzero)), SwiftShader driver)";
        assert_eq!(adapter_name("WebGL2", [angle, "", ""], None), (format!("WebGL2 · {angle}"), true));
    }
}
