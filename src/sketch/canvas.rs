//! Drawing on a sketch: brushes for the four bands, ridge and valley strokes, an eraser for
//! strokes, flood fill of a band region, and undo/redo per stroke. Positions are in sketch
//! pixels (0..[`SKETCH_PX`], fractional); the page maps pointer positions to them.

use super::{BANDS, SKETCH_PX, STROKE_PX, Sketch};

/// What a brush does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tool {
    /// Paints level-set band 0..=3 (round brush of the chosen size).
    Band(u8),
    /// Draws a ridge stroke ([`STROKE_PX`] wide).
    Ridge,
    /// Draws a valley stroke ([`STROKE_PX`] wide).
    Valley,
    /// Clears ridge and valley strokes under a round brush of the chosen size.
    Eraser,
    /// Fills the connected region of one band under the click with band 0..=3.
    Fill(u8),
}

/// Most strokes kept for undo.
pub const UNDO_DEPTH: usize = 64;
/// Brush diameters the canvas accepts (pixels).
pub const BRUSH_PX: std::ops::RangeInclusive<f32> = 1.0..=64.0;

/// A sketch being drawn, with its undo and redo history.
#[derive(Clone, Debug)]
pub struct Canvas {
    sketch: Sketch,
    undo: Vec<Sketch>,
    redo: Vec<Sketch>,
    last: Option<(f32, f32)>,
    tool: Tool,
    brush_px: f32,
    /// Incremented on every change of the sketch (strokes, undo, redo, clear, load).
    revision: u64,
}

impl Default for Canvas {
    fn default() -> Self {
        Self::new(Sketch::filled(1))
    }
}

impl Canvas {
    /// A canvas showing `sketch`, with no history.
    pub fn new(sketch: Sketch) -> Self {
        Self { sketch, undo: Vec::new(), redo: Vec::new(), last: None, tool: Tool::Band(2), brush_px: 12.0, revision: 0 }
    }

    /// The sketch as drawn so far.
    pub fn sketch(&self) -> &Sketch {
        &self.sketch
    }

    /// Changes counter: differs whenever the sketch differs from the last time it was read.
    pub fn revision(&self) -> u64 {
        self.revision
    }

    /// The current tool.
    pub fn tool(&self) -> Tool {
        self.tool
    }

    /// Chooses the tool for the next stroke.
    pub fn set_tool(&mut self, tool: Tool) {
        self.tool = match tool {
            Tool::Band(b) => Tool::Band(b.min(BANDS as u8 - 1)),
            Tool::Fill(b) => Tool::Fill(b.min(BANDS as u8 - 1)),
            t => t,
        };
    }

    /// Brush diameter for bands and the eraser (pixels).
    pub fn brush_px(&self) -> f32 {
        self.brush_px
    }

    /// Sets the brush diameter (clamped to [`BRUSH_PX`]).
    pub fn set_brush_px(&mut self, px: f32) {
        self.brush_px = if px.is_finite() { px.clamp(*BRUSH_PX.start(), *BRUSH_PX.end()) } else { 12.0 };
    }

    fn remember(&mut self) {
        self.undo.push(self.sketch.clone());
        if self.undo.len() > UNDO_DEPTH {
            self.undo.remove(0);
        }
        self.redo.clear();
    }

    /// Starts a stroke at (`x`, `y`) with the current tool (a fill happens at once).
    pub fn press(&mut self, x: f32, y: f32) {
        if !(x.is_finite() && y.is_finite()) {
            return;
        }
        self.remember();
        if let Tool::Fill(b) = self.tool {
            self.fill(x, y, b);
            self.last = None;
        } else {
            self.dab(x, y);
            self.last = Some((x, y));
        }
        self.revision += 1;
    }

    /// Continues the stroke to (`x`, `y`) (a straight segment from the last point).
    pub fn drag(&mut self, x: f32, y: f32) {
        let Some((x0, y0)) = self.last else { return };
        if !(x.is_finite() && y.is_finite()) {
            return;
        }
        let steps = ((x - x0).abs().max((y - y0).abs()) * 2.0).ceil().max(1.0) as usize;
        for k in 1..=steps {
            let t = k as f32 / steps as f32;
            self.dab(x0 + (x - x0) * t, y0 + (y - y0) * t);
        }
        self.last = Some((x, y));
        self.revision += 1;
    }

    /// Ends the stroke.
    pub fn release(&mut self) {
        self.last = None;
    }

    /// Whether a stroke is in progress.
    pub fn drawing(&self) -> bool {
        self.last.is_some()
    }

    /// One brush imprint centred on (`x`, `y`).
    fn dab(&mut self, x: f32, y: f32) {
        let d = match self.tool {
            Tool::Ridge | Tool::Valley => STROKE_PX as f32,
            _ => self.brush_px,
        };
        let r = d / 2.0;
        let n = SKETCH_PX as i64;
        let (x0, x1) = (((x - r).floor() as i64).max(0), ((x + r).ceil() as i64).min(n - 1));
        let (y0, y1) = (((y - r).floor() as i64).max(0), ((y + r).ceil() as i64).min(n - 1));
        for py in y0..=y1 {
            for px in x0..=x1 {
                // Pixel centres within the brush: a square of STROKE_PX for strokes (the
                // format's 3 px width), a disc for the others.
                let (dx, dy) = (px as f32 + 0.5 - x, py as f32 + 0.5 - y);
                let inside = match self.tool {
                    Tool::Ridge | Tool::Valley => dx.abs() <= r && dy.abs() <= r,
                    _ => dx * dx + dy * dy <= r * r || (dx.abs() <= 0.5 && dy.abs() <= 0.5),
                };
                if !inside {
                    continue;
                }
                let p = py as usize * SKETCH_PX + px as usize;
                match self.tool {
                    Tool::Band(b) => self.sketch.band[p] = b,
                    Tool::Ridge => self.sketch.ridge[p] = true,
                    Tool::Valley => self.sketch.valley[p] = true,
                    Tool::Eraser => {
                        self.sketch.ridge[p] = false;
                        self.sketch.valley[p] = false;
                    }
                    Tool::Fill(_) => {}
                }
            }
        }
    }

    /// Gives the 4-connected region of the band under (`x`, `y`) band `b`.
    fn fill(&mut self, x: f32, y: f32, b: u8) {
        let n = SKETCH_PX;
        if x < 0.0 || y < 0.0 || x >= n as f32 || y >= n as f32 {
            return;
        }
        let start = y as usize * n + x as usize;
        let from = self.sketch.band[start];
        if from == b {
            return;
        }
        let mut stack = vec![start];
        self.sketch.band[start] = b;
        while let Some(p) = stack.pop() {
            let (px, py) = (p % n, p / n);
            let mut visit = |q: usize| {
                if self.sketch.band[q] == from {
                    self.sketch.band[q] = b;
                    stack.push(q);
                }
            };
            if px > 0 {
                visit(p - 1);
            }
            if px + 1 < n {
                visit(p + 1);
            }
            if py > 0 {
                visit(p - n);
            }
            if py + 1 < n {
                visit(p + n);
            }
        }
    }

    /// Undoes the last stroke; false if there is none.
    pub fn undo(&mut self) -> bool {
        let Some(prev) = self.undo.pop() else { return false };
        self.redo.push(std::mem::replace(&mut self.sketch, prev));
        self.last = None;
        self.revision += 1;
        true
    }

    /// Redoes the last undone stroke; false if there is none.
    pub fn redo(&mut self) -> bool {
        let Some(next) = self.redo.pop() else { return false };
        self.undo.push(std::mem::replace(&mut self.sketch, next));
        self.last = None;
        self.revision += 1;
        true
    }

    /// Whether there is something to undo / redo.
    pub fn history(&self) -> (bool, bool) {
        (!self.undo.is_empty(), !self.redo.is_empty())
    }

    /// Replaces the sketch (clear, import, an example, a variant); undoable.
    pub fn load(&mut self, sketch: Sketch) {
        self.remember();
        self.sketch = sketch;
        self.last = None;
        self.revision += 1;
    }

    /// Clears the sketch to one band without strokes; undoable.
    pub fn clear(&mut self) {
        self.load(Sketch::filled(1));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn count(v: &[bool]) -> usize {
        v.iter().filter(|&&b| b).count()
    }

    #[test]
    fn a_ridge_stroke_is_3_px_wide_and_undo_redo_restore_each_state() {
        let mut c = Canvas::default();
        c.set_tool(Tool::Ridge);
        c.press(50.5, 100.5);
        c.drag(150.5, 100.5);
        c.release();
        // Rows 99..=101 from column 49 to 151: 3 × 103 pixels.
        assert_eq!(count(&c.sketch().ridge), 3 * 103);
        let drawn = c.sketch().clone();
        assert!(c.undo());
        assert_eq!(count(&c.sketch().ridge), 0);
        assert!(c.redo());
        assert_eq!(c.sketch(), &drawn);
        assert!(!c.redo(), "nothing left to redo");
        c.set_tool(Tool::Eraser);
        c.set_brush_px(64.0);
        c.press(100.0, 100.0);
        c.release();
        assert_eq!(count(&c.sketch().ridge), 3 * 103 - 3 * 64, "a 64 px eraser clears 64 columns of the stroke");
    }

    #[test]
    fn fill_changes_exactly_the_connected_band_region() {
        let mut c = Canvas::default();
        // A band-3 ring splits band 1 into an inside and an outside.
        c.set_tool(Tool::Band(3));
        c.set_brush_px(4.0);
        c.press(64.0, 64.0);
        for (x, y) in [(192.0, 64.0), (192.0, 192.0), (64.0, 192.0), (64.0, 64.0)] {
            c.drag(x, y);
        }
        c.release();
        let ring = c.sketch().band.iter().filter(|&&b| b == 3).count();
        c.set_tool(Tool::Fill(2));
        c.press(128.0, 128.0);
        let s = c.sketch();
        assert_eq!(s.band[128 * SKETCH_PX + 128], 2);
        assert_eq!(s.band[5 * SKETCH_PX + 5], 1, "outside the ring stays band 1");
        assert_eq!(s.band.iter().filter(|&&b| b == 3).count(), ring, "the ring is untouched");
        let inside = s.band.iter().filter(|&&b| b == 2).count();
        assert!((124 * 124..=128 * 128).contains(&inside), "{inside} pixels filled");
        assert!(c.undo());
        assert_eq!(c.sketch().band.iter().filter(|&&b| b == 2).count(), 0);
    }

    #[test]
    fn history_keeps_at_most_the_undo_depth_and_clear_is_undoable() {
        let mut c = Canvas::default();
        c.set_tool(Tool::Valley);
        for k in 0..UNDO_DEPTH + 10 {
            c.press(10.0 + k as f32, 10.0);
            c.release();
        }
        let mut undone = 0;
        while c.undo() {
            undone += 1;
        }
        assert_eq!(undone, UNDO_DEPTH);
        c.clear();
        assert!(c.undo());
        let r0 = c.revision();
        c.drag(5.0, 5.0);
        assert_eq!(c.revision(), r0, "a drag without a press draws nothing");
    }
}
