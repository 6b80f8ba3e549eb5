//! The page's whole egui interface over the core: the overlay and, in the sketch world, the
//! sketch panel. What the user asks is applied to the core here (settings, camera mode, the
//! message, variants, blends, relief); only what needs the browser (the clipboard, a file
//! download or picker) goes back to the shell.

use super::sketch::SketchPanel;
use super::{Environment, Overlay};
use crate::app::heightmap::PngKind;
use crate::app::page::PageCore;
use crate::share::ShareState;
use crate::sketch::Sketch;
use crate::world::SourceKind;

/// What the user asked this frame that only the browser can do.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BrowserAsks {
    /// Copy the share link.
    pub copy_link: bool,
    /// Download the sketch as a PNG.
    pub export_sketch: bool,
    /// Open a sketch PNG.
    pub import_sketch: bool,
    /// Download the terrain around the eye.
    pub export: Option<super::ExportAsk>,
    /// Open a GeoTIFF to pin into the learned world.
    pub pin_dem: bool,
    /// Download the world as a bundle.
    pub save_world: bool,
    /// Open a world bundle.
    pub open_world: bool,
}

/// The interface's state between frames.
pub struct PageUi {
    /// The overlay.
    pub overlay: Overlay,
    /// The sketch panel.
    pub panel: SketchPanel,
    examples: Vec<(&'static str, Sketch)>,
    /// When the link was last copied (page clock, ms).
    pub copied_at_ms: Option<f64>,
}

impl PageUi {
    /// The interface for a page opened at `share`.
    pub fn new(share: ShareState) -> Self {
        Self { overlay: Overlay::new(share), panel: SketchPanel::default(), examples: crate::sketch::examples::all(), copied_at_ms: None }
    }

    /// Draws the overlay (and the sketch panel in the sketch world) at page time `now_ms`,
    /// applies what the user asked to `core` and returns what the browser must do.
    pub fn show(&mut self, ctx: &egui::Context, core: &mut PageCore, env: &Environment, now_ms: f64) -> BrowserAsks {
        let copied = self.copied_at_ms.is_some_and(|t| now_ms - t < 2000.0);
        let stats = core.app.stats().clone();
        let app = &mut core.app;
        let (mode, mut speed, mut show_lod, mut refine_on) = (app.controller.mode, app.controller.speed_mps, app.show_lod, core.refine_on);
        let act = self.overlay.show(ctx, &stats, env, mode, &mut speed, &mut show_lod, &mut refine_on, core.message.as_deref(), copied);
        (core.app.controller.speed_mps, core.app.show_lod, core.refine_on) = (speed, show_lod, refine_on);
        if let Some(m) = act.mode {
            core.app.set_camera_mode(m);
        }
        if let Some(s) = act.settings {
            core.app.apply_settings(s);
        }
        if act.dismiss_message {
            core.message = None;
        }
        if act.unpin {
            core.unpin();
        }
        self.heightmap_dialog(ctx, core);
        let mut asks =
            BrowserAsks { copy_link: act.copy_link, export: act.export, pin_dem: act.pin_dem, save_world: act.save_world, open_world: act.open_world, ..Default::default() };
        if core.app.source() == SourceKind::Sketch {
            if let Some(v) = core.variants.take() {
                self.panel.set_variants(ctx, v);
            }
            let busy = core.sketch_busy() || stats.sketch_jobs.in_flight > 0;
            let (relief, extent) = (core.app.settings().relief_m, core.app.settings().extent_m);
            let sk = self.panel.show(ctx, &mut core.app.canvas, relief, extent, busy, &self.examples);
            (asks.export_sketch, asks.import_sketch) = (sk.export, sk.import);
            if sk.variants {
                core.ask_variants();
            }
            if let (Some(alpha), Some((a, b))) = (sk.blend, self.panel.blend_pair()) {
                core.ask_blend(a.clone(), b.clone(), alpha);
            }
            if let Some(r) = sk.relief_m {
                self.overlay.reset(core.set_relief(r));
            }
            if let Some(e) = sk.extent_m {
                self.overlay.reset(core.set_extent(e));
            }
            if sk.frame {
                core.app.frame_sketch();
            }
        }
        asks
    }

    /// The questions a heightmap PNG waiting to be pinned asks ([`PageCore::heightmap`]): its
    /// spacing and, for grey values, the heights of its lowest and highest value; Pin pins it
    /// (what happened goes to the message), Cancel drops it.
    fn heightmap_dialog(&mut self, ctx: &egui::Context, core: &mut PageCore) {
        let Some(p) = core.heightmap.as_mut() else { return };
        let (mut pin, mut cancel) = (false, false);
        egui::Window::new("Pin a heightmap PNG").collapsible(false).resizable(false).anchor(egui::Align2::CENTER_CENTER, [0.0, 0.0]).show(ctx, |ui| {
            ui.label(format!("{}: {} × {} samples", p.name, p.size.0, p.size.1));
            if let Some(side) = &p.sidecar {
                ui.label(egui::RichText::new(format!("answers from {side}")).small());
            }
            ui.horizontal(|ui| {
                ui.label("spacing");
                ui.add(egui::DragValue::new(&mut p.spacing_m).range(0.01..=1000.0).speed(0.1).suffix(" m"));
            });
            match p.kind {
                PngKind::Grey { max_value } => {
                    ui.horizontal(|ui| {
                        ui.label("0 =");
                        ui.add(egui::DragValue::new(&mut p.low_m).speed(1.0).suffix(" m"));
                        ui.label(format!("{max_value} ="));
                        ui.add(egui::DragValue::new(&mut p.high_m).speed(1.0).suffix(" m"));
                    });
                }
                PngKind::TerrainRgb => {
                    ui.label("terrain-RGB: the heights it encodes");
                }
            }
            ui.horizontal(|ui| {
                let b = ui.button("Pin");
                self.overlay.buttons.insert("pin_heightmap", b.rect);
                pin = b.clicked();
                cancel = ui.button("Cancel").clicked();
            });
        });
        if pin {
            core.message = Some(core.pin_heightmap().unwrap_or_else(|e| e));
        }
        if cancel {
            core.cancel_heightmap();
        }
    }

    /// The page's statistics as JSON ([`super::stats_json`]).
    pub fn stats_json(&self, core: &PageCore, env: &Environment, frame_work: &std::collections::VecDeque<[f64; 7]>, device_restarts: u32, link_too_long: u32) -> String {
        super::stats_json(core, env, &self.panel, &self.overlay, frame_work, device_restarts, link_too_long)
    }
}
