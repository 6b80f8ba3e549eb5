//! Fluvial erosion of the learned world's 128 m field: valleys that branch and run on across
//! tiles, carved where the water of many samples gathers, instead of round basins between the
//! generator's bumps.
//!
//! The model is the stream-power law with hillslope diffusion, solved implicitly along the
//! flow (Braun & Willett 2013), with the generator's own field as the uplift that keeps the
//! relief: per iteration,
//! - the field is filled ([`super::drainage::fill_depressions`] with its ε gradient) only to
//!   route the water: each sample sends it to its steepest lower 8-neighbour on the filled
//!   surface, so a closed basin spills over its lowest sill;
//! - every sample's drainage area `A` (samples, itself included) is summed down the flow;
//! - receivers before their donors (a walk up the flow from the outlets: the same bits as
//!   lowest first, without a sort), each sample above its receiver moves towards it:
//!   `h' = (h + F·h'_r + α·h₀) / (1 + F + α)` with `F = K·√A / d` (`d` the step in samples),
//!   `h₀` the generator's height and `α` the pull back to it; a sample in a lake (not above its
//!   receiver) is only pulled back to `h₀`;
//! - hillslope diffusion: each free sample moves `κ` of the way to the mean of its 4
//!   neighbours.
//!
//! Where water gathers (large `A`) the channel is cut deep; ridges (A = 1) barely move. A
//! river's bed follows the generator's profile with a lag of `K/α·√A` samples, so the sills
//! of basins along it are cut through. Erosion alone does not leave a field that drains: the
//! slopes into a lake are cut down to its floor, and a sample between two diagonal gullies can
//! be a pit to the 4-connected fill. The learned world's 32 m drainage stages drain what is
//! left ([`super::learned`]). Water routed to 4-neighbours only, or slopes
//! cut no lower than a lake's surface, gave a world further from the real ranges
//! (eval-tcm, 4 seeds: realism ratio with the drainage statistics 0.35–0.52 against 0.30). The border (and any `fixed`
//! sample) is never changed and takes all water: a block drained this way keeps the edges it
//! shares with its neighbours, and is a pure function of its input. Only IEEE-exact operations
//! are used (`√`, `+`, `×`, `/`), so the page's WebAssembly makes the same bits as native code.

use super::drainage::{FLAT_GRADIENT_M, fill_around};

/// The erosion's parameters (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Erosion {
    /// Iterations.
    pub iterations: usize,
    /// Stream-power coefficient `K` per iteration (1/√samples).
    pub k: f32,
    /// Pull back to the generator's heights per iteration (dimensionless).
    pub alpha: f32,
    /// Hillslope diffusion per iteration: the fraction of the way to the 4-neighbour mean
    /// (0–1).
    pub kappa: f32,
    /// Width (samples) of the band along the border over which the change fades in: 0 at the
    /// border, all of it from this far in (a smoothstep). A block eroded with its border fixed
    /// would keep the generator's heights there as a rim beside the lowered inside.
    pub taper: f32,
}

/// No receiver: the sample is an outlet (border, fixed) or NaN.
const NONE: usize = usize::MAX;

/// Erodes the `n`×`n` heightfield `h` (metres, row-major) in place (see the module
/// documentation), its border and the `fixed` samples (`n`², true: fixed) kept. NaN samples are
/// left as they are and take no water.
pub fn erode(h: &mut [f32], n: usize, fixed: Option<&[bool]>, p: &Erosion) {
    assert_eq!(h.len(), n * n, "a {n}×{n} field has {} samples, not {}", n * n, h.len());
    let outlet = |q: usize| q.is_multiple_of(n) || q % n == n - 1 || q / n == 0 || q / n == n - 1 || fixed.is_some_and(|f| f[q]) || h[q].is_nan();
    let free: Vec<bool> = (0..n * n).map(|q| !outlet(q)).collect();
    let start = h.to_vec();
    let mut filled = vec![0f32; n * n];
    let mut order: Vec<usize> = Vec::with_capacity(n * n);
    let mut donors = Donors::default();
    let mut receiver = vec![NONE; n * n];
    let mut step = vec![1f32; n * n];
    let mut area = vec![0f32; n * n];
    let mut next = vec![0f32; n * n];
    for _ in 0..p.iterations {
        filled.copy_from_slice(h);
        fill_around(&mut filled, n, fixed, FLAT_GRADIENT_M);
        for q in 0..n * n {
            receiver[q] = NONE;
            if !free[q] {
                continue;
            }
            let (x, y) = ((q % n) as i64, (q / n) as i64);
            let mut best = 0f32;
            for (dx, dy) in [(-1i64, -1i64), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
                let r = (y + dy) as usize * n + (x + dx) as usize;
                let d = if dx != 0 && dy != 0 { std::f32::consts::SQRT_2 } else { 1.0 };
                let drop = (filled[q] - filled[r]) / d;
                if drop > best {
                    (best, receiver[q], step[q]) = (drop, r, d);
                }
            }
        }
        receivers_first(&receiver, &mut order, &mut donors);
        area.iter_mut().zip(&free).for_each(|(a, &f)| *a = if f { 1.0 } else { 0.0 });
        for &q in order.iter().rev() {
            if receiver[q] != NONE {
                area[receiver[q]] += area[q];
            }
        }
        for &q in &order {
            let r = receiver[q];
            if r == NONE {
                continue;
            }
            let f = if h[q] > h[r] { p.k * area[q].sqrt() / step[q] } else { 0.0 };
            h[q] = (h[q] + f * h[r] + p.alpha * start[q]) / (1.0 + f + p.alpha);
        }
        if p.kappa > 0.0 {
            next.copy_from_slice(h);
            for q in (0..n * n).filter(|&q| free[q]) {
                let around = [q - 1, q + 1, q - n, q + n].map(|r| h[r]);
                if around.iter().all(|v| !v.is_nan()) {
                    let mean = (around[0] + around[1] + around[2] + around[3]) * 0.25;
                    next[q] = h[q] + p.kappa * (mean - h[q]);
                }
            }
            h.copy_from_slice(&next);
        }
    }
    if p.taper > 0.0 {
        for (q, (z, z0)) in h.iter_mut().zip(&start).enumerate() {
            let (x, y) = (q % n, q / n);
            let d = x.min(y).min(n - 1 - x).min(n - 1 - y) as f32 / p.taper;
            if d < 1.0 {
                let w = d * d * (3.0 - 2.0 * d);
                *z = z0 + w * (*z - z0);
            }
        }
    }
}

/// The samples' donors (the samples whose receiver they are), as compressed lists.
#[derive(Default)]
struct Donors {
    /// Where each sample's donors start in `list` (`n² + 1` entries).
    start: Vec<usize>,
    list: Vec<usize>,
    /// Where the next donor of each sample goes while `list` is filled.
    next: Vec<usize>,
}

/// Every sample in an order where each comes after its receiver (outlets first), into `order`:
/// a walk up the flow from the outlets. Each update of an iteration reads only its own sample
/// and its receiver's, and the drainage areas are sums of whole samples (exact in `f32`), so
/// any such order gives the same bits as sorting by height; this one takes O(n²) instead of a
/// sort.
fn receivers_first(receiver: &[usize], order: &mut Vec<usize>, d: &mut Donors) {
    let len = receiver.len();
    d.start.clear();
    d.start.resize(len + 1, 0);
    for &r in receiver.iter().filter(|&&r| r != NONE) {
        d.start[r + 1] += 1;
    }
    for q in 0..len {
        d.start[q + 1] += d.start[q];
    }
    d.list.clear();
    d.list.resize(d.start[len], 0);
    d.next.clear();
    d.next.extend_from_slice(&d.start[..len]);
    for (q, &r) in receiver.iter().enumerate().filter(|&(_, &r)| r != NONE) {
        d.list[d.next[r]] = q;
        d.next[r] += 1;
    }
    order.clear();
    order.extend((0..len).filter(|&q| receiver[q] == NONE));
    let mut k = 0;
    while k < order.len() {
        let r = order[k];
        order.extend_from_slice(&d.list[d.start[r]..d.start[r + 1]]);
        k += 1;
    }
    assert_eq!(order.len(), len, "the flow has a cycle");
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::drainage::depression_fraction;

    const SOME: Erosion = Erosion { iterations: 40, k: 0.02, alpha: 0.01, kappa: 0.1, taper: 0.0 };

    /// Seeded bumps: the sum of a few sines, 0–300 m.
    fn bumps(n: usize) -> Vec<f32> {
        (0..n * n)
            .map(|p| {
                let (x, y) = ((p % n) as f32, (p / n) as f32);
                150.0 + 60.0 * (x * 0.41).sin() * (y * 0.37).cos() + 50.0 * (x * 0.13 + y * 0.21).sin() + 40.0 * (y * 0.29 - x * 0.17).cos()
            })
            .collect()
    }

    /// The border and the fixed samples keep their heights exactly, and more than half of the
    /// other samples are lowered.
    #[test]
    fn the_border_and_fixed_samples_are_kept_bit_for_bit() {
        let n = 48;
        let h0 = bumps(n);
        let mut fixed = vec![false; n * n];
        (20..26).for_each(|y| fixed[y * n + 20..y * n + 26].fill(true));
        let mut h = h0.clone();
        erode(&mut h, n, Some(&fixed), &SOME);
        for q in 0..n * n {
            let border = q % n == 0 || q % n == n - 1 || q / n == 0 || q / n == n - 1;
            if border || fixed[q] {
                assert_eq!(h[q].to_bits(), h0[q].to_bits(), "sample {q}");
            }
        }
        let lowered = h.iter().zip(&h0).filter(|(a, b)| *a < *b).count();
        assert!(lowered > n * n / 2, "{lowered} of {} samples lowered", n * n);
    }

    /// A valley falling 2 m per sample to the west border, dammed by a ridge 40 m high across
    /// it: the dam leaves a closed depression upstream (over 5 % of the field). Erosion (the
    /// stream-power term, no pull back) cuts the dam where the valley's water crosses it: its
    /// crest on the valley floor comes down by over 30 m, and the valley below it is lowered.
    #[test]
    fn erosion_cuts_through_a_dam_across_a_valley() {
        let n = 48;
        let h0: Vec<f32> = (0..n * n)
            .map(|p| {
                let (x, y) = ((p % n) as f32, (p / n) as f32);
                2.0 * x + 3.0 * (y - 24.0).abs() + 40.0 * (-((x - 16.0) / 2.0).powi(2)).exp()
            })
            .collect();
        assert!(depression_fraction(&h0, n, 0.5) > 0.05);
        let mut h = h0.clone();
        erode(&mut h, n, None, &Erosion { iterations: 60, k: 0.05, alpha: 0.0, kappa: 0.0, taper: 0.0 });
        let sill = |f: &[f32]| (14..19).map(|x| f[24 * n + x]).fold(f32::MIN, f32::max);
        assert!(sill(&h) < sill(&h0) - 30.0, "dam crest on the valley floor {} → {}", sill(&h0), sill(&h));
        assert!(h[24 * n + 8] < h0[24 * n + 8] - 5.0, "valley floor below the dam {} → {}", h0[24 * n + 8], h[24 * n + 8]);
    }

    /// The update order puts every sample once, after its receiver, on a branching flow: a
    /// comb of 40 samples whose teeth drain into a spine that drains into an outlet, the
    /// samples numbered against the flow (so that index order would be wrong).
    #[test]
    fn receivers_first_lists_every_sample_once_and_after_its_receiver() {
        let len = 40;
        // Sample 39 is the outlet; 30..39 the spine (k drains to k + 1); the rest are teeth
        // draining to the spine sample k % 9 + 30.
        let receiver: Vec<usize> = (0..len)
            .map(|k| {
                if k == 39 {
                    NONE
                } else if k >= 30 {
                    k + 1
                } else {
                    k % 9 + 30
                }
            })
            .collect();
        let (mut order, mut donors) = (Vec::new(), Donors::default());
        receivers_first(&receiver, &mut order, &mut donors);
        let mut at = vec![usize::MAX; len];
        for (pos, &q) in order.iter().enumerate() {
            assert_eq!(at[q], usize::MAX, "sample {q} listed twice");
            at[q] = pos;
        }
        assert!(at.iter().all(|&p| p < len), "a sample is missing");
        for q in 0..len {
            if receiver[q] != NONE {
                assert!(at[receiver[q]] < at[q], "sample {q} before its receiver {}", receiver[q]);
            }
        }
        // The same lists on reuse of the buffers.
        let first = order.clone();
        receivers_first(&receiver, &mut order, &mut donors);
        assert_eq!(order, first);
    }

    /// The same input makes the same bits; no iterations change nothing.
    #[test]
    fn erosion_is_a_pure_function_of_its_input() {
        let n = 32;
        let (mut a, mut b) = (bumps(n), bumps(n));
        erode(&mut a, n, None, &SOME);
        erode(&mut b, n, None, &SOME);
        assert_eq!(a, b);
        let mut c = bumps(n);
        erode(&mut c, n, None, &Erosion { iterations: 0, ..SOME });
        assert_eq!(c, bumps(n));
    }
}
