//! The page's whole egui interface over the core: the overlay and, in the sketch world, the
//! sketch panel. What the user asks is applied to the core here (settings, camera mode, the
//! message, variants, blends, relief); only what needs the browser (the clipboard, a file
//! download or picker) goes back to the shell.

use super::sketch::SketchPanel;
use super::{Environment, Overlay};
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
    /// Download the terrain around the eye in this format.
    pub export: Option<crate::dem::formats::Format>,
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
        let mut asks =
            BrowserAsks { copy_link: act.copy_link, export: act.export, pin_dem: act.pin_dem, save_world: act.save_world, open_world: act.open_world, ..Default::default() };
        if core.app.source() == SourceKind::Sketch {
            if let Some(v) = core.variants.take() {
                self.panel.set_variants(ctx, v);
            }
            let busy = core.sketch_busy() || stats.sketch_jobs.in_flight > 0;
            let relief = core.app.settings().relief_m;
            let sk = self.panel.show(ctx, &mut core.app.canvas, relief, busy, &self.examples);
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
            if sk.frame {
                core.app.frame_sketch();
            }
        }
        asks
    }

    /// The page's statistics as JSON ([`super::stats_json`]).
    pub fn stats_json(&self, core: &PageCore, env: &Environment, frame_work: &std::collections::VecDeque<[f64; 7]>, device_restarts: u32, link_too_long: u32) -> String {
        super::stats_json(core, env, &self.panel, &self.overlay, frame_work, device_restarts, link_too_long)
    }
}
