//! Connected regions of a [`SKETCH_PX`]² sketch grid: band regions (4-connected) and stroke
//! components (8-connected), for the extractor's fragment filter and for tidying made sketches.

use super::{SKETCH_PX, Sketch};

/// Connected components of a [`SKETCH_PX`]² grid: a label per pixel (`usize::MAX` outside
/// every component) and each label's size.
pub(crate) struct Components {
    /// Each pixel's component (`usize::MAX` outside every one).
    pub(crate) label: Vec<usize>,
    /// Each component's pixel count, by label.
    pub(crate) size: Vec<usize>,
}

impl Components {
    /// Components of the pixels where `inside` holds, joined where `same(p, q)` holds for
    /// neighbours p and q (4-neighbours, or 8 with `diagonal`).
    fn of(inside: impl Fn(usize) -> bool, same: impl Fn(usize, usize) -> bool, diagonal: bool) -> Self {
        let n = SKETCH_PX;
        let mut label = vec![usize::MAX; n * n];
        let mut size = Vec::new();
        let mut stack = Vec::new();
        for start in 0..n * n {
            if label[start] != usize::MAX || !inside(start) {
                continue;
            }
            let id = size.len();
            let mut count = 0;
            label[start] = id;
            stack.push(start);
            while let Some(p) = stack.pop() {
                count += 1;
                for q in neighbours(p, diagonal) {
                    if label[q] == usize::MAX && inside(q) && same(p, q) {
                        label[q] = id;
                        stack.push(q);
                    }
                }
            }
            size.push(count);
        }
        Self { label, size }
    }

    /// Band regions: 4-connected pixels of one band.
    pub(crate) fn of_bands(s: &Sketch) -> Self {
        Self::of(|_| true, |p, q| s.band[p] == s.band[q], false)
    }

    /// 8-connected pixels of a mask (strokes).
    pub(crate) fn of_mask(mask: &[bool]) -> Self {
        Self::of(|p| mask[p], |_, _| true, true)
    }

    /// The pixels of each component, by label.
    pub(crate) fn members(&self) -> Vec<Vec<usize>> {
        let mut m = vec![Vec::new(); self.size.len()];
        for (p, &l) in self.label.iter().enumerate() {
            if l != usize::MAX {
                m[l].push(p);
            }
        }
        m
    }

    /// Whether `pixels` are exactly one whole component here.
    pub(crate) fn is_whole(&self, pixels: &[usize]) -> bool {
        let l = self.label[pixels[0]];
        l != usize::MAX && self.size[l] == pixels.len() && pixels.iter().all(|&p| self.label[p] == l)
    }
}

/// The 4- (or 8-) neighbours of pixel `p` inside the sketch.
pub(crate) fn neighbours(p: usize, diagonal: bool) -> impl Iterator<Item = usize> {
    let n = SKETCH_PX as i64;
    let (y, x) = ((p / SKETCH_PX) as i64, (p % SKETCH_PX) as i64);
    const STEPS: [(i64, i64); 8] = [(0, 1), (1, 0), (0, -1), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)];
    STEPS[..if diagonal { 8 } else { 4 }]
        .iter()
        .map(move |(dy, dx)| (y + dy, x + dx))
        .filter(move |&(y, x)| y >= 0 && x >= 0 && y < n && x < n)
        .map(move |(y, x)| (y * n + x) as usize)
}
