//! The sketch panel: the drawing canvas (bands, ridge, valley, eraser, fill, brush size,
//! undo/redo, clear), the examples, the relief, import/export, variants as thumbnails and the
//! slider between the sketch and another one. It edits the app's [`Canvas`] directly and
//! reports what needs the shell (files, the worker).

use crate::sketch::canvas::{BRUSH_PX, Canvas, Tool};
use crate::sketch::{SKETCH_PX, Sketch};
use crate::world::sketched::{EXTENT_M, RELIEF_M};

/// What the user asked of the shell this frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SketchActions {
    /// Download the sketch as a PNG.
    pub export: bool,
    /// Open a sketch PNG.
    pub import: bool,
    /// Propose variants of the sketch.
    pub variants: bool,
    /// Blend the sketch (α = 1) with the chosen partner (α = 0) at this α.
    pub blend: Option<f32>,
    /// A new relief (metres).
    pub relief_m: Option<f64>,
    /// A new extent (metres across).
    pub extent_m: Option<f64>,
    /// Put the camera where it shows the whole sketch.
    pub frame: bool,
}

/// Thumbnails of proposed variants: each sketch and a shaded picture of its terrain.
pub struct Variant {
    /// The variant sketch.
    pub sketch: Sketch,
    texture: egui::TextureHandle,
}

/// Panel state between frames.
#[derive(Default)]
pub struct SketchPanel {
    texture: Option<(u64, egui::TextureHandle)>,
    variants: Vec<Variant>,
    /// The sketch the slider blends with (a variant or an example), and the sketch it blends
    /// from (the canvas when the partner was chosen).
    partner: Option<(Sketch, Sketch)>,
    alpha: f32,
    /// Where the canvas was drawn last frame (points), for tests that draw with the pointer.
    pub canvas_rect: Option<egui::Rect>,
    /// Where the panel's buttons were drawn last frame (points), by name, for tests that
    /// click them.
    pub buttons: std::collections::BTreeMap<String, egui::Rect>,
}

/// Side of the canvas on screen (points).
const CANVAS_PT: f32 = 320.0;

/// A grey hillshade of terrain `h` (`side`², any scale) as a thumbnail of `out`² pixels.
pub fn hillshade(h: &[f32], side: usize, out: usize) -> egui::ColorImage {
    let (lo, hi) = h.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    let scale = 255.0 / (hi - lo).max(1e-6);
    let step = side / out;
    let at = |x: usize, y: usize| h[y.min(side - 1) * side + x.min(side - 1)] * scale;
    let mut px = Vec::with_capacity(out * out);
    for y in 0..out {
        for x in 0..out {
            let (sx, sy) = (x * step, y * step);
            let dx = at(sx + step, sy) - at(sx.saturating_sub(step), sy);
            let dy = at(sx, sy + step) - at(sx, sy.saturating_sub(step));
            let shade = (0.75 - 0.02 * (dx + dy) / step as f32).clamp(0.0, 1.0);
            let g = (shade * 220.0 + (at(sx, sy) - lo * scale) * 0.14) as u8;
            px.push(egui::Color32::from_gray(g));
        }
    }
    egui::ColorImage::new([out, out], px)
}

impl SketchPanel {
    /// Shows proposed variants (sketch and terrain on the 0–255 scale each).
    pub fn set_variants(&mut self, ctx: &egui::Context, variants: Vec<(Sketch, Vec<f32>)>) {
        self.variants = variants
            .into_iter()
            .enumerate()
            .map(|(k, (sketch, h))| Variant { sketch, texture: ctx.load_texture(format!("variant{k}"), hillshade(&h, SKETCH_PX, 64), egui::TextureOptions::LINEAR) })
            .collect();
    }

    /// Draws the panel for `canvas` with `relief_m` and `extent_m` (metres across); `busy`
    /// says a terrain or variants are being made.
    pub fn show(&mut self, ctx: &egui::Context, canvas: &mut Canvas, relief_m: f64, extent_m: f64, busy: bool, examples: &[(&str, Sketch)]) -> SketchActions {
        let mut act = SketchActions::default();
        self.buttons.clear();
        let mut rects = std::collections::BTreeMap::new();
        let mut note = |name: &str, r: &egui::Response| {
            rects.insert(name.to_string(), r.rect);
        };
        egui::Window::new("Sketch").anchor(egui::Align2::RIGHT_TOP, [-8.0, 8.0]).resizable(false).default_width(CANVAS_PT).show(ctx, |ui| {
            ui.horizontal_wrapped(|ui| {
                let tool = canvas.tool();
                let mut pick = |ui: &mut egui::Ui, t: Tool, label: &str, tip: &str| {
                    if ui.selectable_label(tool == t, label).on_hover_text(tip).clicked() {
                        canvas.set_tool(t);
                    }
                };
                for b in 0..4u8 {
                    pick(ui, Tool::Band(b), &format!("▮{b}"), "paint level-set band (0 lowest, 3 highest)");
                }
                pick(ui, Tool::Ridge, "ridge", "draw a ridge line");
                pick(ui, Tool::Valley, "valley", "draw a valley line");
                pick(ui, Tool::Eraser, "eraser", "erase ridge and valley lines");
                let fill_band = match tool {
                    Tool::Band(b) | Tool::Fill(b) => b,
                    _ => 2,
                };
                pick(ui, Tool::Fill(fill_band), &format!("fill {fill_band}"), "fill a band region with the band chosen last");
            });
            let mut size = canvas.brush_px();
            if ui.add(egui::Slider::new(&mut size, BRUSH_PX).text("brush px")).changed() {
                canvas.set_brush_px(size);
            }
            self.canvas_widget(ui, canvas);
            ui.horizontal(|ui| {
                let (can_undo, can_redo) = canvas.history();
                let r = ui.add_enabled(can_undo, egui::Button::new("Undo"));
                note("undo", &r);
                if r.clicked() {
                    canvas.undo();
                }
                let r = ui.add_enabled(can_redo, egui::Button::new("Redo"));
                note("redo", &r);
                if r.clicked() {
                    canvas.redo();
                }
                let r = ui.button("Clear");
                note("clear", &r);
                if r.clicked() {
                    canvas.clear();
                }
                let r = ui.button("Export PNG");
                note("export", &r);
                if r.clicked() {
                    act.export = true;
                }
                let r = ui.button("Import PNG");
                note("import", &r);
                if r.clicked() {
                    act.import = true;
                }
                let r = ui.button("Frame the sketch").on_hover_text("put the 3-D view where it shows the whole sketch");
                note("frame", &r);
                if r.clicked() {
                    act.frame = true;
                }
                if busy {
                    // Text, not a spinner, which would repaint between paced frames.
                    ui.label("making terrain…");
                }
            });
            ui.horizontal_wrapped(|ui| {
                ui.label("Examples:");
                for (name, s) in examples {
                    if crate::ui::compact_button(ui, *name).clicked() {
                        canvas.load(s.clone());
                    }
                }
            });
            let mut relief = relief_m;
            if ui.add(egui::Slider::new(&mut relief, RELIEF_M).logarithmic(true).text("relief m")).drag_stopped() || (relief != relief_m && !ui.ctx().egui_is_using_pointer()) {
                act.relief_m = Some(relief);
            }
            // Whole metres (512 and 8,192 exactly: a slider that rounds to fewer digits would
            // move the 8 km sketch to 8,190 m the first frame it is drawn); a drag asks for one
            // terrain, at its end.
            let mut extent = extent_m;
            let r = ui
                .add(egui::Slider::new(&mut extent, EXTENT_M).logarithmic(true).integer().text("extent m"))
                .on_hover_text("how wide the sketch is on the ground: 512 m (the sketch format's scale, with 2 m detail) to 8,192 m");
            note("extent", &r);
            if extent != extent_m && (r.drag_stopped() || !ui.ctx().egui_is_using_pointer()) {
                act.extent_m = Some(extent);
            }
            ui.separator();
            ui.horizontal(|ui| {
                let r = ui.button("Variants").on_hover_text("sketches near this one (VAE), each made into terrain");
                note("variants", &r);
                if r.clicked() {
                    act.variants = true;
                }
                if !self.variants.is_empty() {
                    ui.label("click one to adopt it, ⇄ to blend with it");
                }
            });
            ui.horizontal(|ui| {
                for (k, v) in self.variants.iter().enumerate() {
                    ui.vertical(|ui| {
                        let r = ui.add(egui::Button::image(egui::Image::new(&v.texture).fit_to_exact_size(egui::vec2(64.0, 64.0))));
                        note(&format!("variant{k}"), &r);
                        if r.clicked() {
                            canvas.load(v.sketch.clone());
                        }
                        let r = crate::ui::compact_button(ui, "⇄");
                        note(&format!("blend{k}"), &r);
                        if r.clicked() {
                            self.partner = Some((v.sketch.clone(), canvas.sketch().clone()));
                            self.alpha = 1.0;
                        }
                    });
                }
            });
            // The blend row is always there (greyed out until ⇄ picks a partner): a row that
            // appears grows the window a frame late, and a click in that frame is lost.
            let chosen = self.partner.is_some();
            ui.add_enabled_ui(chosen, |ui| {
                ui.horizontal(|ui| {
                    let resp = blend_bar(ui, &mut self.alpha);
                    note("blend_slider", &resp);
                    if resp.changed() {
                        act.blend = Some(self.alpha);
                    }
                    ui.label(if chosen { format!("blend {:.2} (1 = yours)", self.alpha) } else { "blend: ⇄ picks a variant".into() });
                });
            });
        });
        self.buttons = rects;
        act
    }

    /// Number of variants shown.
    pub fn variant_count(&self) -> usize {
        self.variants.len()
    }

    /// The sketch (from) and partner the blend slider works with, if one was chosen.
    pub fn blend_pair(&self) -> Option<(&Sketch, &Sketch)> {
        self.partner.as_ref().map(|(partner, from)| (from, partner))
    }

    fn canvas_widget(&mut self, ui: &mut egui::Ui, canvas: &mut Canvas) {
        let rev = canvas.revision();
        if self.texture.as_ref().is_none_or(|t| t.0 != rev) {
            let image = egui::ColorImage::from_rgb([SKETCH_PX, SKETCH_PX], &canvas.sketch().to_rgb());
            match &mut self.texture {
                Some((r, tex)) => {
                    tex.set(image, egui::TextureOptions::NEAREST);
                    *r = rev;
                }
                None => self.texture = Some((rev, ui.ctx().load_texture("sketch", image, egui::TextureOptions::NEAREST))),
            }
        }
        let (rect, resp) = ui.allocate_exact_size(egui::vec2(CANVAS_PT, CANVAS_PT), egui::Sense::click_and_drag());
        if let Some((_, tex)) = &self.texture {
            ui.painter().image(tex.id(), rect, egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)), egui::Color32::WHITE);
        }
        self.canvas_rect = Some(rect);
        let to_px = |p: egui::Pos2| ((p.x - rect.min.x) / rect.width() * SKETCH_PX as f32, (p.y - rect.min.y) / rect.height() * SKETCH_PX as f32);
        if let Some(p) = resp.interact_pointer_pos() {
            let (x, y) = to_px(p);
            if resp.drag_started() || (resp.clicked() && !canvas.drawing()) {
                canvas.press(x, y);
            } else if resp.dragged() {
                canvas.drag(x, y);
            }
        }
        if resp.drag_stopped() || resp.clicked() {
            canvas.release();
        }
        // The brush outline under the pointer.
        if let Some(p) = resp.hover_pos() {
            let r = match canvas.tool() {
                Tool::Ridge | Tool::Valley => crate::sketch::STROKE_PX as f32,
                _ => canvas.brush_px(),
            } / 2.0
                * rect.width()
                / SKETCH_PX as f32;
            ui.painter().circle_stroke(p, r.max(2.0), egui::Stroke::new(1.0, egui::Color32::WHITE));
        }
    }
}

/// Width (points) of the blend bar.
const BLEND_BAR_PT: f32 = 180.0;

/// A horizontal bar for α in 0..=1 that takes a click as well as a drag: on a slow page a
/// quick click's press and release land in one frame, which egui's slider (it senses drags
/// only) ignores. The response is marked changed when α changes.
fn blend_bar(ui: &mut egui::Ui, alpha: &mut f32) -> egui::Response {
    let (rect, mut resp) = ui.allocate_exact_size(egui::vec2(BLEND_BAR_PT, ui.spacing().interact_size.y), egui::Sense::click_and_drag());
    if let Some(p) = resp.interact_pointer_pos() {
        let a = ((p.x - rect.left()) / rect.width()).clamp(0.0, 1.0);
        if a != *alpha {
            *alpha = a;
            resp.mark_changed();
        }
    }
    let visuals = ui.style().interact(&resp);
    let rail = egui::Rect::from_center_size(rect.center(), egui::vec2(rect.width(), 4.0));
    ui.painter().rect_filled(rail, 2.0, ui.visuals().widgets.inactive.bg_fill);
    ui.painter().circle(egui::pos2(rect.left() + *alpha * rect.width(), rect.center().y), rect.height() / 2.5, visuals.bg_fill, visuals.fg_stroke);
    resp
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs the panel for one frame with `events`, returning its actions.
    fn frame(ctx: &egui::Context, panel: &mut SketchPanel, canvas: &mut Canvas, events: Vec<egui::Event>, t: f64) -> SketchActions {
        let input = egui::RawInput { screen_rect: Some(egui::Rect::from_min_size(egui::Pos2::ZERO, egui::vec2(1280.0, 900.0))), time: Some(t), events, ..Default::default() };
        let mut act = SketchActions::default();
        ctx.run_pass(input, |ctx| act = panel.show(ctx, canvas, 800.0, 8192.0, false, &[])).drop_without_applying_deltas();
        act
    }

    fn button(pos: egui::Pos2, pressed: bool) -> egui::Event {
        egui::Event::PointerButton { pos, button: egui::PointerButton::Primary, pressed, modifiers: Default::default() }
    }

    /// The extent slider asks for nothing until it is moved (8,192 m drawn as it is, not
    /// rounded to another extent), and a click at its left end asks for 512 m exactly.
    #[test]
    fn the_extent_slider_asks_for_nothing_untouched_and_512_m_at_its_left_end() {
        let ctx = egui::Context::default();
        let mut panel = SketchPanel::default();
        let mut canvas = Canvas::new(Sketch::filled(1));
        let mut t = 0.0;
        let mut run = |panel: &mut SketchPanel, canvas: &mut Canvas, events: Vec<egui::Event>| {
            t += 0.1;
            frame(&ctx, panel, canvas, events, t)
        };
        for _ in 0..5 {
            let act = run(&mut panel, &mut canvas, vec![]);
            assert_eq!((act.extent_m, act.relief_m), (None, None));
        }
        let r = panel.buttons["extent"];
        let left = egui::pos2(r.left() + 1.0, r.center().y);
        let mut asked = Vec::new();
        for events in [vec![egui::Event::PointerMoved(left)], vec![button(left, true)], vec![button(left, false)], vec![]] {
            asked.extend(run(&mut panel, &mut canvas, events).extent_m);
        }
        assert_eq!(asked, vec![512.0]);
    }

    /// Before ⇄ the blend slider takes no click; choosing ⇄ beside a variant enables it; a
    /// click at 10 % of its width in the very next frame (press and release two frames apart) asks for one blend at α 0.1 ± 0.01, and a
    /// click at 70 % whose move, press and release land in one frame asks for one at α 0.7 ± 0.01.
    #[test]
    fn a_click_on_the_blend_slider_asks_for_one_blend_at_that_alpha_even_within_one_frame() {
        let ctx = egui::Context::default();
        let mut panel = SketchPanel::default();
        let mut canvas = Canvas::new(Sketch::filled(1));
        panel.set_variants(&ctx, vec![(Sketch::filled(2), vec![0.0; SKETCH_PX * SKETCH_PX])]);
        let mut t = 0.0;
        let mut run = |panel: &mut SketchPanel, canvas: &mut Canvas, events: Vec<egui::Event>| {
            t += 0.1;
            frame(&ctx, panel, canvas, events, t)
        };
        for _ in 0..3 {
            run(&mut panel, &mut canvas, vec![]);
        }
        let early = panel.buttons["blend_slider"].center();
        for events in [vec![egui::Event::PointerMoved(early), button(early, true), button(early, false)], vec![]] {
            assert_eq!(run(&mut panel, &mut canvas, events).blend, None);
        }
        let blend = panel.buttons["blend0"].center();
        run(&mut panel, &mut canvas, vec![egui::Event::PointerMoved(blend)]);
        run(&mut panel, &mut canvas, vec![button(blend, true)]);
        run(&mut panel, &mut canvas, vec![button(blend, false)]);
        assert!(panel.blend_pair().is_some(), "⇄ did not choose a partner");
        let slider = panel.buttons["blend_slider"];
        let at = egui::pos2(slider.left() + 0.1 * slider.width(), slider.center().y);
        let mut asked = Vec::new();
        for events in [vec![egui::Event::PointerMoved(at), button(at, true)], vec![], vec![button(at, false)], vec![]] {
            asked.extend(run(&mut panel, &mut canvas, events).blend);
        }
        assert_eq!(asked.len(), 1, "blends asked: {asked:?}");
        assert!((asked[0] - 0.1).abs() < 0.01, "blends asked: {asked:?}, slider {slider:?}");
        // A quick click on a slow page: press and release arrive in the same frame.
        let at = egui::pos2(slider.left() + 0.7 * slider.width(), slider.center().y);
        let mut asked = Vec::new();
        for events in [vec![egui::Event::PointerMoved(at), button(at, true), button(at, false)], vec![]] {
            asked.extend(run(&mut panel, &mut canvas, events).blend);
        }
        assert_eq!(asked.len(), 1, "blends asked: {asked:?}");
        assert!((asked[0] - 0.7).abs() < 0.01, "blends asked: {asked:?}");
    }

    /// On a page drawing a frame every 2 s, a click on ⇄ whose press and release land in
    /// frames 2 s apart chooses the partner once the context is set up by `ui::set_up` (and is
    /// lost with egui's own 0.8 s click bound, which is what lost CI's click).
    #[test]
    fn a_click_spread_over_frames_two_seconds_apart_chooses_the_blend_partner_after_set_up() {
        for set_up in [false, true] {
            let ctx = egui::Context::default();
            if set_up {
                crate::ui::set_up(&ctx, false);
            }
            let mut panel = SketchPanel::default();
            let mut canvas = Canvas::new(Sketch::filled(1));
            panel.set_variants(&ctx, vec![(Sketch::filled(2), vec![0.0; SKETCH_PX * SKETCH_PX])]);
            let mut t = 0.0;
            for _ in 0..3 {
                t += 2.0;
                frame(&ctx, &mut panel, &mut canvas, vec![], t);
            }
            let blend = panel.buttons["blend0"].center();
            for events in [vec![egui::Event::PointerMoved(blend), button(blend, true)], vec![button(blend, false)], vec![]] {
                t += 2.0;
                frame(&ctx, &mut panel, &mut canvas, events, t);
            }
            assert_eq!(panel.blend_pair().is_some(), set_up, "set up: {set_up}");
        }
    }
}
