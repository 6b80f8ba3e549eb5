//! Drainage: filling closed depressions so that water from every sample can run off the
//! tile's border.
//!
//! Real terrain drains; a generator's output (and noise) is full of small pits. The fill is
//! priority-flood with an ε gradient (Barnes, Lehman & Mulla 2014): the border samples keep
//! their heights and are the outlets; every other sample is raised, if needed, to just above
//! the lowest height at which it can spill to the border through its 4 neighbours. A filled
//! lake becomes a surface rising by [`FLAT_GRADIENT_M`] per sample away from its outlet, so
//! every sample has a strictly descending 4-connected path to the border.
//!
//! [`breach_depressions`] drains mostly by carving instead: a channel along each pit's spill
//! path, its sides opened to a V ([`open_channels`]), lakes only for the deepest parts.
//!
//! The border is never changed, so draining one tile changes nothing along the edges it shares
//! with its neighbours, and a drained tile is still a pure function of its input.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Rise (metres per sample) given to filled flats so that they drain.
pub const FLAT_GRADIENT_M: f32 = 1e-3;

/// The priority-flood walk over an `n`×`n` field: samples come out lowest first, starting
/// from the border (the outlets); each one's unvisited 4-neighbours are then taken in. A
/// sequence number keeps the order of equal heights fixed (first in, first out), so the
/// result does not depend on the heap's tie-breaking. NaN samples are never visited.
struct Flood {
    n: usize,
    done: Vec<bool>,
    /// (height key ([`height_key`]) << 32 | sequence number, sample): one integer comparison
    /// orders two entries as (f32 comparison of the heights, then first in first out) did.
    heap: BinaryHeap<Reverse<(u64, u32)>>,
    seq: u64,
}

/// A key whose unsigned order is the order of the heights by `f32` comparison (every world
/// made so far depends on it; NaN never enters the flood): the IEEE bits with the sign flipped
/// for positive heights and all bits flipped for negative ones, −0 taken as +0 (they compare
/// equal).
fn height_key(z: f32) -> u64 {
    let b = if z == 0.0 { 0 } else { z.to_bits() };
    (if b >> 31 == 1 { !b } else { b | 1 << 31 }) as u64
}

impl Flood {
    /// The walk with every border sample of `h` queued at its height, then every `fixed`
    /// sample (outlets too, in row-major order).
    fn from_outlets(h: &[f32], n: usize, fixed: Option<&[bool]>) -> Self {
        assert!(n * n <= u32::MAX as usize, "a {n}×{n} field is too large for the flood");
        let mut f = Self { n, done: vec![false; n * n], heap: BinaryHeap::new(), seq: 0 };
        let border = (0..n).flat_map(|i| [i, (n - 1) * n + i, i * n, i * n + n - 1]);
        let fixed = fixed.into_iter().flat_map(|m| m.iter().enumerate().filter(|&(_, &k)| k).map(|(p, _)| p));
        for p in border.chain(fixed) {
            if !f.done[p] && !h[p].is_nan() {
                f.done[p] = true;
                f.push(p, h[p]);
            }
        }
        f
    }

    /// Queues sample `p` at height `z`.
    fn push(&mut self, p: usize, z: f32) {
        // Each sample is queued at most once per walk (n² < 2³²) but a walk may be restarted
        // on the same flood: the sequence number must still fit its 32 bits.
        assert!(self.seq < 1 << 32, "more than 2³² samples queued");
        self.heap.push(Reverse((height_key(z) << 32 | self.seq, p as u32)));
        self.seq += 1;
    }

    /// The lowest queued sample, if any.
    fn pop(&mut self) -> Option<usize> {
        self.heap.pop().map(|Reverse((_, p))| p as usize)
    }

    /// The 4-neighbours of `p` not visited yet and not NaN in `h`, now marked visited
    /// (`usize::MAX` for none).
    fn take_neighbours(&mut self, p: usize, h: &[f32]) -> [usize; 4] {
        let (n, x, y) = (self.n, p % self.n, p / self.n);
        let mut out = [usize::MAX; 4];
        for (k, (qx, qy)) in [(x.wrapping_sub(1), y), (x + 1, y), (x, y.wrapping_sub(1)), (x, y + 1)].into_iter().enumerate() {
            if qx < n && qy < n && !self.done[qy * n + qx] && !h[qy * n + qx].is_nan() {
                self.done[qy * n + qx] = true;
                out[k] = qy * n + qx;
            }
        }
        out
    }
}

/// Fills the closed depressions of the `n`×`n` heightfield `h` (metres, row-major) in place,
/// its border fixed. Each filled sample is raised to at least `gradient_m` (rounded up to the
/// next representable height) above the sample it drains to; 0 makes level lakes. NaN samples
/// are left as they are and do not drain. Returns the number of samples raised.
pub fn fill_depressions(h: &mut [f32], n: usize, gradient_m: f32) -> usize {
    fill_around(h, n, None, gradient_m)
}

/// [`fill_depressions`] with the `fixed` samples (`n`², true: fixed) kept as they are and
/// draining like the border: outlets.
pub(super) fn fill_around(h: &mut [f32], n: usize, fixed: Option<&[bool]>, gradient_m: f32) -> usize {
    assert_eq!(h.len(), n * n, "a {n}×{n} field has {} samples, not {}", n * n, h.len());
    let mut flood = Flood::from_outlets(h, n, fixed);
    let mut raised = 0;
    while let Some(p) = flood.pop() {
        let z = h[p];
        for q in flood.take_neighbours(p, h).into_iter().filter(|&q| q != usize::MAX) {
            let floor = if gradient_m > 0.0 { above(z, gradient_m) } else { z };
            if h[q] < floor {
                h[q] = floor;
                raised += 1;
            }
            flood.push(q, h[q]);
        }
    }
    raised
}

/// Makes every sample of the `n`×`n` heightfield `h` (metres, row-major) drain to the border
/// mostly by carving, as rivers do, instead of by filling lakes: closed depressions are first
/// raised to at most `max_depth_m` below their fill level (the deeper parts of deep basins
/// become level lakes, as [`fill_depressions`] would make them), then a channel is cut from
/// each remaining pit along its spill path — the priority-flood path to the border — lowering
/// each sample on it to `gradient_m` (rounded to the next representable height) below the one
/// upstream until the path already descends. No sample is lowered by much more than
/// `max_depth_m`; where the channel would have to go below a border sample the pit is raised
/// instead. A channel one sample wide would be a slot; its sides are then lowered to a V
/// whose sides drop `wall_m` per sample towards it, by no more than the channel is deep
/// ([`open_channels`]), and the few pits that leaves are filled. The border is never
/// changed; NaN samples are left as they are and do not drain. Returns (samples raised,
/// samples lowered).
pub fn breach_depressions(h: &mut [f32], n: usize, max_depth_m: f32, wall_m: f32, gradient_m: f32) -> (usize, usize) {
    breach_depressions_around(h, n, None, max_depth_m, wall_m, gradient_m)
}

/// [`breach_depressions`] with the `fixed` samples (`n`², true: fixed; e.g. terrain a user
/// pinned) kept exactly as they are and taken as outlets like the border: the rest drains to
/// them or to the border, and no channel is cut into them.
pub fn breach_depressions_around(h: &mut [f32], n: usize, fixed: Option<&[bool]>, max_depth_m: f32, wall_m: f32, gradient_m: f32) -> (usize, usize) {
    breach(h, n, fixed, max_depth_m, wall_m, gradient_m, Raise::Yes)
}

/// [`breach_depressions_around`] that only carves: every closed depression with a way out
/// to the border (or to the `fixed` samples) no higher than its pit gets its channel, as
/// there, but none is raised. A basin whose spill point is a border sample above its pit
/// (its way out is beyond the border) is left as it is, for a later pass over a block that
/// holds it whole; the pits beside the opened channels are left too. Returns (0, samples
/// lowered).
pub fn carve_depressions_around(h: &mut [f32], n: usize, fixed: Option<&[bool]>, wall_m: f32, gradient_m: f32) -> (usize, usize) {
    breach(h, n, fixed, f32::INFINITY, wall_m, gradient_m, Raise::No)
}

/// Drains the `n`×`n` block `h` (metres, row-major) as seen at `factor` times its spacing: `h`
/// area-averaged over `factor`² samples is carved ([`carve_depressions_around`]) or, with
/// `max_depth_m`, breached ([`breach_depressions_around`]: pits raised where their way out is
/// beyond the border, basins deeper than that filled level), its border, the cells holding a
/// `fixed` sample and the cells beside those kept; the change is then interpolated bilinearly
/// (cell centres, clamped at the edges) onto every sample of `h` but its border and the
/// `fixed` ones. A channel carved
/// this way is `factor` samples wide at its floor, where one carved at `h`'s own spacing is a
/// notch that area-averaging closes again. Interpolated, a channel one cell wide spreads over
/// about three at half its depth in the averaged field: draining at several factors in turn,
/// coarsest first, makes up for it. `wall_m` and `gradient_m` are per sample of `h`;
/// NaN cells change nothing. `n` must be a multiple of `factor`.
pub fn drain_coarser(h: &mut [f32], n: usize, fixed: Option<&[bool]>, factor: usize, max_depth_m: Option<f32>, wall_m: f32, gradient_m: f32) {
    assert_eq!(h.len(), n * n, "a {n}×{n} field has {} samples, not {}", n * n, h.len());
    assert!(factor >= 1 && n.is_multiple_of(factor), "{n} samples are not a multiple of {factor}");
    let c = n / factor;
    let mut avg = vec![0f32; c * c];
    let mut held = vec![false; c * c];
    let share = 1.0 / (factor * factor) as f32;
    for y in 0..n {
        for x in 0..n {
            let cell = (y / factor) * c + x / factor;
            avg[cell] += h[y * n + x] * share;
            held[cell] |= fixed.is_some_and(|f| f[y * n + x]);
        }
    }
    // The cells beside a held one are held too: a sample next to a fixed one then interpolates
    // between two unchanged cells, where half the change of the cell beside would be a step.
    let held = crate::sketch::extract::dilate(&held, c, 1);
    let before = avg.clone();
    let held = held.iter().any(|&b| b).then_some(&held[..]);
    let (wall, gradient) = (wall_m * factor as f32, gradient_m * factor as f32);
    match max_depth_m {
        Some(depth) => {
            breach_depressions_around(&mut avg, c, held, depth, wall, gradient);
        }
        None => {
            carve_depressions_around(&mut avg, c, held, wall, gradient);
        }
    }
    let change: Vec<f32> = avg.iter().zip(&before).map(|(a, b)| if (a - b).is_finite() { a - b } else { 0.0 }).collect();
    let at = |i: i64, j: i64| change[j.clamp(0, c as i64 - 1) as usize * c + i.clamp(0, c as i64 - 1) as usize];
    let f = factor as f32;
    for y in 1..n - 1 {
        let v = (y as f32 + 0.5) / f - 0.5;
        let (j, tv) = (v.floor() as i64, v - v.floor());
        for x in 1..n - 1 {
            if fixed.is_some_and(|m| m[y * n + x]) {
                continue;
            }
            let u = (x as f32 + 0.5) / f - 0.5;
            let (i, tu) = (u.floor() as i64, u - u.floor());
            let top = (1.0 - tu) * at(i, j) + tu * at(i + 1, j);
            let bottom = (1.0 - tu) * at(i, j + 1) + tu * at(i + 1, j + 1);
            h[y * n + x] += (1.0 - tv) * top + tv * bottom;
        }
    }
}

/// Whether [`breach`] may raise samples (fill).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Raise {
    Yes,
    No,
}

/// [`breach_depressions_around`], raising samples only if `raise` says so.
fn breach(h: &mut [f32], n: usize, fixed: Option<&[bool]>, max_depth_m: f32, wall_m: f32, gradient_m: f32, raise: Raise) -> (usize, usize) {
    assert_eq!(h.len(), n * n, "a {n}×{n} field has {} samples, not {}", n * n, h.len());
    if let Some(f) = fixed {
        assert_eq!(f.len(), n * n, "a fixed mask of {} samples for a {n}×{n} field", f.len());
    }
    let original = h.to_vec();
    let mut raised = 0;
    if max_depth_m.is_finite() {
        let mut level = original.clone();
        fill_around(&mut level, n, fixed, 0.0);
        for (z, l) in h.iter_mut().zip(&level) {
            if *z < l - max_depth_m {
                *z = l - max_depth_m;
                raised += 1;
            }
        }
    }
    const BORDER: usize = usize::MAX;
    let mut parent = vec![BORDER; n * n];
    let mut flood = Flood::from_outlets(h, n, fixed);
    let mut lowered = vec![false; n * n];
    let mut path = Vec::new();
    while let Some(p) = flood.pop() {
        for q in flood.take_neighbours(p, h).into_iter().filter(|&q| q != usize::MAX) {
            parent[q] = p;
            if h[q] <= h[p] {
                // The path from q down to the first sample already low enough (or the border).
                path.clear();
                let (mut a, mut z) = (p, below(h[q], gradient_m));
                while a != BORDER && h[a] >= z {
                    path.push(a);
                    if parent[a] == BORDER {
                        break;
                    }
                    a = parent[a];
                    z = below(z, gradient_m);
                }
                let blocked = path.last().is_some_and(|&b| parent[b] == BORDER);
                if blocked && raise == Raise::No {
                    // No way out below q inside the field: q stays a pit.
                    flood.push(q, h[q]);
                    continue;
                }
                if let Some(&b) = path.last().filter(|_| blocked) {
                    // The channel cannot go below the border sample b: raise q above it.
                    let mut top = h[b];
                    for _ in 0..path.len() {
                        top = above(top, gradient_m);
                    }
                    h[q] = top;
                    raised += 1;
                    path.pop();
                }
                let mut z = h[q];
                for &a in &path {
                    z = below(z, gradient_m);
                    if h[a] > z {
                        h[a] = z;
                        lowered[a] = true;
                    }
                }
            }
            flood.push(q, h[q]);
        }
    }
    let cut: Vec<f32> = (0..n * n).map(|p| if lowered[p] { original[p] - h[p] } else { 0.0 }).collect();
    let opened = open_around(h, n, &cut, wall_m, fixed);
    if opened > 0 && raise == Raise::Yes {
        // Capping the sides at the channel's depth can leave shallow pits beside it.
        raised += fill_around(h, n, fixed, gradient_m);
    }
    (raised, lowered.iter().filter(|&&l| l).count() + opened)
}

/// Lowers the samples beside the channels of the `n`×`n` field `h` (`cut`: how deep the
/// breach cut each sample, 0 off the channels) to the lower envelope of cones around them:
/// a sample `d` samples (8-neighbour chamfer distance) from a channel sample at height z cut
/// c deep goes down to z + `wall_m`·d, but by at most c. The border and NaN samples are not
/// changed. Returns the samples lowered; pits this may leave are for the caller to fill.
pub fn open_channels(h: &mut [f32], n: usize, cut: &[f32], wall_m: f32) -> usize {
    open_around(h, n, cut, wall_m, None)
}

/// [`open_channels`] leaving the `fixed` samples as they are too.
fn open_around(h: &mut [f32], n: usize, cut: &[f32], wall_m: f32, fixed: Option<&[bool]>) -> usize {
    if !(wall_m.is_finite() && wall_m > 0.0) {
        return 0;
    }
    let inner = |p: usize| !p.is_multiple_of(n) && p % n != n - 1 && p / n != 0 && p / n != n - 1 && !fixed.is_some_and(|f| f[p]);
    // Per sample: the lowest cone over it and the depth of the channel sample it comes from.
    let mut cone = vec![(f32::INFINITY, 0f32); n * n];
    let mut heap = BinaryHeap::new();
    for p in (0..n * n).filter(|&p| cut[p] > 0.0) {
        cone[p] = (h[p], cut[p]);
        heap.push(Reverse(height_key(h[p]) << 32 | p as u64));
    }
    let diagonal = wall_m * std::f32::consts::SQRT_2;
    while let Some(Reverse(key)) = heap.pop() {
        let p = (key & u32::MAX as u64) as usize;
        let z = cone[p].0;
        if height_key(z) != key >> 32 {
            continue; // a later, lower cone replaced this entry
        }
        let (x, y) = ((p % n) as i64, (p / n) as i64);
        for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1), (-1, -1), (1, -1), (-1, 1), (1, 1)] {
            let (qx, qy) = (x + dx, y + dy);
            if qx < 0 || qy < 0 || qx >= n as i64 || qy >= n as i64 {
                continue;
            }
            let q = qy as usize * n + qx as usize;
            let zq = z + if dx != 0 && dy != 0 { diagonal } else { wall_m };
            if inner(q) && !h[q].is_nan() && zq < cone[q].0 && zq < h[q] {
                cone[q] = (zq, cone[p].1);
                heap.push(Reverse(height_key(zq) << 32 | q as u64));
            }
        }
    }
    let mut lowered = 0;
    for p in 0..n * n {
        let (z, c) = cone[p];
        let to = z.max(h[p] - c);
        if to < h[p] && cut[p] == 0.0 {
            h[p] = to;
            lowered += 1;
        }
    }
    lowered
}

/// `z - d`, or the next representable value below `z` where `d` is below its precision.
fn below(z: f32, d: f32) -> f32 {
    let s = z - d;
    if s < z { s } else { z.next_down() }
}

/// `z + d`, or the next representable value above `z` where `d` is below its precision.
fn above(z: f32, d: f32) -> f32 {
    let s = z + d;
    if s > z { s } else { z.next_up() }
}

/// Fraction of the `n`×`n` field `h` lying in closed depressions deeper than `depth_m`: the
/// samples that a level fill ([`fill_depressions`] with no gradient) raises by more than it.
pub fn depression_fraction(h: &[f32], n: usize, depth_m: f32) -> f64 {
    let mut filled = h.to_vec();
    fill_depressions(&mut filled, n, 0.0);
    filled.iter().zip(h).filter(|(f, o)| **f - **o > depth_m).count() as f64 / (n * n) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The `n`×`n` field `h` area-averaged over `f`² samples, as `eval-tcm`'s drainage
    /// statistics average the world.
    fn averaged(h: &[f32], n: usize, f: usize) -> Vec<f32> {
        crate::dem::Heightfield::new(n, n, 1.0, h.to_vec()).resample_area(f as f64).expect("a coarser spacing").data
    }

    /// A bowl drained only by a notch one sample wide to a valley mouth at the border: at its
    /// own spacing it drains, averaged over 4×4 samples most of it is a closed depression
    /// again (the notch is a quarter of a cell). Drained at 4× its spacing (carving) the
    /// averaged field has under 15 % of its area in closed depressions deeper than 0.5 m (over
    /// 30 % before; the interpolation spreads a channel one cell wide over three, about half as
    /// deep); nothing rises, and the border and a fixed patch keep their bits.
    #[test]
    fn draining_at_four_times_the_spacing_opens_most_of_a_bowl_that_averaging_over_four_samples_closes() {
        let n = 64;
        let mut h: Vec<f32> = (0..n * n)
            .map(|p| {
                let (x, y) = ((p % n) as f32 - 32.0, (p / n) as f32 - 32.0);
                100.0 + 0.02 * (x * x + y * y)
            })
            .collect();
        for x in 4..=32 {
            h[32 * n + x] = 90.0 + 0.25 * x as f32; // the notch, falling west to the mouth
        }
        for y in 28..36 {
            h[y * n..y * n + 4].fill(80.0); // a valley mouth at the west border, 8 samples wide
        }
        let mut fixed = vec![false; n * n];
        (50..54).for_each(|y| fixed[y * n + 8..y * n + 12].fill(true));
        assert!(depression_fraction(&h, n, 0.5) < 0.001, "the notch drains the bowl at its own spacing");
        let coarse_before = depression_fraction(&averaged(&h, n, 4), n / 4, 0.5);
        assert!(coarse_before > 0.3, "averaged, the bowl is closed: {coarse_before}");
        let h0 = h.clone();
        drain_coarser(&mut h, n, Some(&fixed), 4, None, 8.0, FLAT_GRADIENT_M);
        let coarse_after = depression_fraction(&averaged(&h, n, 4), n / 4, 0.5);
        assert!(coarse_after < 0.15, "averaged after draining at 4×: {coarse_after}");
        assert!(h.iter().zip(&h0).all(|(a, b)| a <= b), "a sample rose");
        for q in 0..n * n {
            let border = q % n == 0 || q % n == n - 1 || q / n == 0 || q / n == n - 1;
            if border || fixed[q] {
                assert_eq!(h[q].to_bits(), h0[q].to_bits(), "sample {q}");
            }
        }
    }

    /// The flood's integer keys order heights exactly as `f32` comparison does: −0 and +0 are
    /// one key, and every other pair of the listed heights (negatives, subnormals, ±∞) is in
    /// the same order by key as by value.
    #[test]
    fn height_keys_order_heights_as_f32_comparison_does_with_minus_zero_equal_to_zero() {
        let v = [f32::NEG_INFINITY, -3.0e38, -1234.5, -1.0, -1e-40, -0.0, 0.0, 1e-45, 1e-40, 1e-3, 1.0, 1.0 + f32::EPSILON, 2.0, 8848.0, 3.0e38, f32::INFINITY];
        assert_eq!(height_key(-0.0), height_key(0.0));
        for a in v {
            for b in v {
                assert_eq!(height_key(a).cmp(&height_key(b)), a.partial_cmp(&b).unwrap(), "{a} vs {b}");
            }
        }
    }

    /// Whether every sample of `h` has a strictly descending 4-connected path to the border
    /// (found by walking from the border upwards).
    fn drains(h: &[f32], n: usize) -> bool {
        drains_to(h, n, &vec![false; n * n])
    }

    /// Whether every sample of `h` has a strictly descending 4-connected path to the border or
    /// to an `outlet` sample.
    fn drains_to(h: &[f32], n: usize, outlet: &[bool]) -> bool {
        let mut ok = vec![false; n * n];
        let mut stack: Vec<usize> = (0..n * n).filter(|&p| p % n == 0 || p % n == n - 1 || p / n == 0 || p / n == n - 1 || outlet[p]).collect();
        stack.iter().for_each(|&p| ok[p] = true);
        while let Some(p) = stack.pop() {
            let (x, y) = (p % n, p / n);
            for (qx, qy) in [(x.wrapping_sub(1), y), (x + 1, y), (x, y.wrapping_sub(1)), (x, y + 1)] {
                if qx < n && qy < n && !ok[qy * n + qx] && h[qy * n + qx] > h[p] {
                    ok[qy * n + qx] = true;
                    stack.push(qy * n + qx);
                }
            }
        }
        ok.iter().all(|&o| o)
    }

    fn noise(n: usize, seed: u64) -> Vec<f32> {
        (0..n * n).map(|p| (crate::grid::mix64(seed ^ p as u64) % 10_000) as f32 * 0.01 + 2000.0).collect()
    }

    /// White noise (100 m range at 2 km) is full of pits; after the fill every sample drains
    /// strictly to the border, the border is bit-identical and no sample went down.
    #[test]
    fn filled_noise_drains_everywhere_and_keeps_its_border() {
        let n = 64;
        let h0 = noise(n, 7);
        assert!(!drains(&h0, n));
        let mut h = h0.clone();
        let raised = fill_depressions(&mut h, n, FLAT_GRADIENT_M);
        assert!(raised > 100, "{raised}");
        assert!(drains(&h, n));
        for p in 0..n * n {
            assert!(h[p] >= h0[p]);
            if p % n == 0 || p % n == n - 1 || p / n == 0 || p / n == n - 1 {
                assert_eq!(h[p].to_bits(), h0[p].to_bits());
            }
        }
        assert_eq!(depression_fraction(&h, n, 0.0), 0.0);
    }

    /// Carving only (the first drainage stage): a bowl 30 m deep below a rim 10 m above the
    /// border, in a field otherwise falling to the border, gets its channel out and drains; a
    /// second bowl in the same field whose floor lies below every border sample is left
    /// exactly as it was; no sample anywhere goes up and the border is kept.
    #[test]
    fn carving_drains_a_bowl_with_a_way_out_and_leaves_one_below_the_border_as_it_is() {
        let n = 64;
        // A dome falling 1 m per sample from the centre column to the border (1,000 m there).
        let mut h0: Vec<f32> = (0..n * n).map(|p| 1000.0 + (31 - ((p % n) as i32 - 31).abs().max(((p / n) as i32 - 31).abs())) as f32).collect();
        let bowl = |h: &mut [f32], cx: i32, cy: i32, floor: f32| {
            for p in 0..n * n {
                let (dx, dy) = ((p % n) as i32 - cx, (p / n) as i32 - cy);
                if dx * dx + dy * dy <= 16 {
                    h[p] = floor + (dx * dx + dy * dy) as f32 * 0.5;
                }
            }
        };
        bowl(&mut h0, 20, 20, 990.0); // the rim there is ~1,020 m: its floor is below the border (1,000 m)
        bowl(&mut h0, 44, 44, 1005.0); // its floor above the border: a way out exists
        let mut h = h0.clone();
        let (raised, lowered) = carve_depressions_around(&mut h, n, None, 16.0, FLAT_GRADIENT_M);
        assert_eq!(raised, 0);
        assert!(lowered > 0);
        assert!((0..n * n).all(|p| h[p] <= h0[p]), "a sample went up");
        for p in 0..n * n {
            let (x, y) = ((p % n) as i32, (p / n) as i32);
            if x == 0 || y == 0 || x == n as i32 - 1 || y == n as i32 - 1 {
                assert_eq!(h[p].to_bits(), h0[p].to_bits(), "border sample {p} changed");
            }
            if (x - 20).pow(2) + (y - 20).pow(2) <= 16 {
                assert_eq!(h[p].to_bits(), h0[p].to_bits(), "the bowl below the border changed at {p}");
            }
        }
        // Everything but the low bowl drains: taken as an outlet, every sample has a strictly
        // descending path to the border or into it.
        let low: Vec<bool> = (0..n * n).map(|p| ((p % n) as i32 - 20).pow(2) + ((p / n) as i32 - 20).pow(2) <= 16).collect();
        assert!(!drains(&h0, n) && !drains_to(&h0, n, &low), "the high bowl is closed before");
        assert!(drains_to(&h, n, &low), "the high bowl drains after");
        assert!(depression_fraction(&h, n, 0.0) > 0.0, "the low bowl is still closed");
    }

    /// Breached around a fixed square (pinned terrain: a 200 m deep bowl in the middle of
    /// white noise), the square is bit-identical and every other sample drains strictly to
    /// the border or to the square; without the square fixed the bowl is changed.
    #[test]
    fn breached_noise_around_a_fixed_square_keeps_it_and_drains_to_it_or_the_border() {
        let n = 64;
        let mut h0 = noise(n, 13);
        let fixed: Vec<bool> = (0..n * n).map(|p| (20..36).contains(&(p % n)) && (24..40).contains(&(p / n))).collect();
        for p in (0..n * n).filter(|&p| fixed[p]) {
            let (dx, dy) = ((p % n) as f32 - 27.5, (p / n) as f32 - 31.5);
            h0[p] = 1900.0 + (dx * dx + dy * dy);
        }
        let mut h = h0.clone();
        let (raised, lowered) = breach_depressions_around(&mut h, n, Some(&fixed), 20.0, 16.0, FLAT_GRADIENT_M);
        assert!(raised + lowered > 100, "{raised} {lowered}");
        assert!(drains_to(&h, n, &fixed));
        assert!((0..n * n).filter(|&p| fixed[p]).all(|p| h[p].to_bits() == h0[p].to_bits()), "a fixed sample changed");
        let mut free = h0.clone();
        breach_depressions(&mut free, n, 20.0, 16.0, FLAT_GRADIENT_M);
        assert!((0..n * n).any(|p| fixed[p] && free[p] != h0[p]), "the bowl drains when not fixed");
    }

    /// White noise (100 m range) breached with a 20 m depth limit: every sample drains
    /// strictly to the border, the border is bit-identical, no sample went down by more than
    /// the limit (plus the channels' gradient), channels were cut, and fewer samples were
    /// raised than a fill raises.
    #[test]
    fn breached_noise_drains_keeps_its_border_and_is_lowered_at_most_the_depth_limit() {
        let n = 64;
        let h0 = noise(n, 11);
        let mut h = h0.clone();
        let (raised, lowered) = breach_depressions(&mut h, n, 20.0, 16.0, FLAT_GRADIENT_M);
        let filled_raised = fill_depressions(&mut h0.clone(), n, FLAT_GRADIENT_M);
        println!("breach: {raised} raised, {lowered} lowered; fill: {filled_raised} raised");
        assert!(drains(&h, n));
        assert!(lowered > 100 && raised < filled_raised, "{raised} {lowered} {filled_raised}");
        for p in 0..n * n {
            assert!(h0[p] - h[p] <= 20.0 + n as f32 * n as f32 * FLAT_GRADIENT_M, "{p}: {} → {}", h0[p], h[p]);
            if p % n == 0 || p % n == n - 1 || p / n == 0 || p / n == n - 1 {
                assert_eq!(h[p].to_bits(), h0[p].to_bits());
            }
        }
    }

    /// A bowl 10 m deep spilling over one low border sample, breached with a 4 m limit: its
    /// centre is raised to 4 m below the spill height (within the gradient over its radius),
    /// a channel at most 4 m deep is cut through the rim to the spill point, and every
    /// sample drains.
    #[test]
    fn a_bowl_breached_with_a_depth_limit_keeps_a_lake_4_m_below_its_spill_height() {
        let n = 33;
        let c = 16.0f32;
        let mut h: Vec<f32> = (0..n * n).map(|p| 100.0 + (((p % n) as f32 - c).powi(2) + ((p / n) as f32 - c).powi(2)).sqrt().min(c) * 10.0 / c).collect();
        h[16] = 99.0; // the spill point on the top border, below the bowl's floor
        let before = h.clone();
        let (_, lowered) = breach_depressions(&mut h, n, 4.0, f32::INFINITY, FLAT_GRADIENT_M);
        let spill = before[n + 16];
        let centre = h[16 * n + 16];
        assert!((centre - (spill - 4.0)).abs() <= 40.0 * FLAT_GRADIENT_M, "centre {centre}, spill {spill}");
        assert!(lowered >= 10, "{lowered}");
        assert!(h.iter().zip(&before).all(|(a, b)| b - a <= 4.0 + 0.05), "lowered by more than 4 m");
        assert!(drains(&h, n));
    }

    /// A bowl 10 m deep whose rim is lowered at one border sample fills to its spill height
    /// (the height of the bowl's sample beside that border sample, 109.375 m), within the ε
    /// gradient over the bowl's radius; a plane is left as it is.
    #[test]
    fn a_bowl_fills_to_its_spill_height_and_a_plane_is_unchanged() {
        let n = 33;
        let c = 16.0f32;
        let mut h: Vec<f32> = (0..n * n).map(|p| 100.0 + (((p % n) as f32 - c).powi(2) + ((p / n) as f32 - c).powi(2)).sqrt().min(c) * 10.0 / c).collect();
        h[16] = 109.0; // the spill point on the top border
        let before = h.clone();
        fill_depressions(&mut h, n, FLAT_GRADIENT_M);
        let spill = before[n + 16];
        assert_eq!(spill, 109.375);
        let centre = h[16 * n + 16];
        assert!(centre >= spill && centre <= spill + 17.0 * FLAT_GRADIENT_M, "{centre}");
        assert!((depression_fraction(&before, n, 0.5) - before.iter().filter(|&&v| v < spill - 0.5).count() as f64 / (n * n) as f64).abs() < 1e-12);
        let mut plane: Vec<f32> = (0..n * n).map(|p| (p % n) as f32 * 2.0).collect();
        let p0 = plane.clone();
        assert_eq!(fill_depressions(&mut plane, n, FLAT_GRADIENT_M), 0);
        assert_eq!(plane, p0);
    }
}
