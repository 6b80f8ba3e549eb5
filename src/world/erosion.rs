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
//! - every sample's drainage area `A` (samples, itself included) is summed down the flow.
//!   Where `A` is below [`Erosion::spread_below`] (hillslopes) a sample's water is shared
//!   among all its lower 8-neighbours in proportion to the square of the drop per unit
//!   distance (multiple flow directions, taken highest first); from there on (channels) it
//!   all goes to the steepest one. With one direction everywhere (D8), every hillslope
//!   sample's water runs down one of eight straight lines, and the stream-power term cut
//!   them as parallel straight rills along the eight directions, seen from above as
//!   hatching (`terrain eval-tcm`'s grid alignment figure);
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
    /// Drainage area (samples) below which a sample's water spreads over all its lower
    /// 8-neighbours (see the module documentation); 0: every sample sends all of it to its
    /// steepest lower neighbour (D8).
    pub spread_below: f32,
}

/// No receiver: the sample is an outlet (border, fixed) or NaN.
const NONE: usize = usize::MAX;

/// The 8 neighbours (dx, dy) and the distance to each (samples).
const NEIGHBOURS: [(i64, i64, f32); 8] = [
    (-1, -1, std::f32::consts::SQRT_2),
    (0, -1, 1.0),
    (1, -1, std::f32::consts::SQRT_2),
    (-1, 0, 1.0),
    (1, 0, 1.0),
    (-1, 1, std::f32::consts::SQRT_2),
    (0, 1, 1.0),
    (1, 1, std::f32::consts::SQRT_2),
];

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
    let mut by_height: Vec<u64> = Vec::with_capacity(n * n);
    let mut drops = vec![0f32; 8 * n * n];
    let mut step = vec![1f32; n * n];
    let mut area = vec![0f32; n * n];
    let mut next = vec![0f32; n * n];
    for _ in 0..p.iterations {
        filled.copy_from_slice(h);
        fill_around(&mut filled, n, fixed, FLAT_GRADIENT_M);
        flow_directions(&filled, &free, &mut drops, &mut receiver, &mut step);
        receivers_first(&receiver, &mut order, &mut donors);
        area.iter_mut().zip(&free).for_each(|(a, &f)| *a = if f { 1.0 } else { 0.0 });
        if p.spread_below > 0.0 {
            spread_areas(&filled, &drops, &free, &receiver, p.spread_below, &mut by_height, &mut area);
        } else {
            for &q in order.iter().rev() {
                if receiver[q] != NONE {
                    area[receiver[q]] += area[q];
                }
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

/// The flow on the filled `n`×`n` field `filled`: for each free sample, the drop per unit
/// distance to each of its 8 neighbours (`drops`, 8 per sample in the order of
/// [`NEIGHBOURS`], 0 where not lower), its steepest lower neighbour (`receiver`; [`NONE`] for
/// samples that are not free or have none) and the distance to it (`step`, samples). The
/// samples that are not free keep their drops (0 from the start).
fn flow_directions(filled: &[f32], free: &[bool], drops: &mut [f32], receiver: &mut [usize], step: &mut [f32]) {
    let n = filled.len().isqrt();
    for q in 0..n * n {
        receiver[q] = NONE;
        if !free[q] {
            continue;
        }
        let (x, y) = ((q % n) as i64, (q / n) as i64);
        let mut best = 0f32;
        for (t, (dx, dy, d)) in NEIGHBOURS.into_iter().enumerate() {
            let r = (y + dy) as usize * n + (x + dx) as usize;
            let drop = (filled[q] - filled[r]) / d;
            drops[8 * q + t] = if drop > 0.0 { drop } else { 0.0 };
            if drop > best {
                (best, receiver[q], step[q]) = (drop, r, d);
            }
        }
    }
}

/// Sums the drainage areas `area` (1 on each free sample, 0 elsewhere, on entry) down the
/// flow on `filled`: the free samples taken highest first (ties by index: the same order,
/// and so the same bits, on every platform), each passes its area on to all its lower
/// 8-neighbours in proportion to the square of its drop per unit distance to each (`drops`,
/// 8 per sample in the order of [`NEIGHBOURS`], 0 where not lower) while it is below
/// `spread_below`, and all of it to `receiver` from there on. `by_height` is scratch.
fn spread_areas(filled: &[f32], drops: &[f32], free: &[bool], receiver: &[usize], spread_below: f32, by_height: &mut Vec<u64>, area: &mut [f32]) {
    let n = filled.len().isqrt();
    // A free sample is never on the border, so all 8 neighbours exist.
    let offset: [isize; 8] = NEIGHBOURS.map(|(dx, dy, _)| dy as isize * n as isize + dx as isize);
    // Each free sample as (its height's bits made to sort like the height, inverted so the
    // highest comes first; its index).
    let descending = |f: f32| {
        let b = f.to_bits();
        !(if b >> 31 == 1 { !b } else { b | 0x8000_0000 })
    };
    by_height.clear();
    by_height.extend((0..n * n).filter(|&q| free[q]).map(|q| (u64::from(descending(filled[q])) << 32) | q as u64));
    by_height.sort_unstable();
    for &key in by_height.iter() {
        let q = (key & 0xffff_ffff) as usize;
        let a = area[q];
        let d = &drops[8 * q..][..8];
        let w: [f32; 8] = std::array::from_fn(|t| d[t] * d[t]);
        let sum = w.iter().sum::<f32>();
        // Spread: to every lower neighbour its share of the squared drops; else all to the
        // receiver. Without branches on the neighbours (this loop is most of the cost).
        let per_weight = if a < spread_below && sum > 0.0 { a / sum } else { 0.0 };
        let to_receiver = if per_weight > 0.0 { NONE } else { receiver[q] };
        for (t, &o) in offset.iter().enumerate() {
            let r = q.wrapping_add_signed(o);
            let share = if r == to_receiver { a } else { w[t] * per_weight };
            area[r] += if d[t] > 0.0 { share } else { 0.0 };
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
/// and its receiver's, and the D8 drainage areas summed in the reverse of this order are sums
/// of whole samples (exact in `f32`), so any such order gives the same bits as sorting by
/// height; this one takes O(n²) instead of a sort.
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

    const SOME: Erosion = Erosion { iterations: 40, k: 0.02, alpha: 0.01, kappa: 0.1, taper: 0.0, spread_below: 0.0 };

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
        erode(&mut h, n, None, &Erosion { iterations: 60, k: 0.05, alpha: 0.0, kappa: 0.0, taper: 0.0, spread_below: 0.0 });
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

    /// The 8-fold harmonic of the erosion depth (start − end) around a ring of radius 10–24
    /// samples of an eroded cone, relative to the mean depth there: 0 for an erosion that
    /// cuts the same at every angle.
    fn eightfold_depth(spread_below: f32) -> f64 {
        let n = 64;
        let c = (n as f32 - 1.0) / 2.0;
        let h0: Vec<f32> = (0..n * n).map(|p| 400.0 - 12.0 * ((p % n) as f32 - c).hypot((p / n) as f32 - c)).collect();
        let mut h = h0.clone();
        erode(&mut h, n, None, &Erosion { spread_below, ..SOME });
        let (mut re, mut im, mut sum) = (0f64, 0f64, 0f64);
        for p in 0..n * n {
            let (x, y) = ((p % n) as f64 - c as f64, (p / n) as f64 - c as f64);
            let r = x.hypot(y);
            if (10.0..24.0).contains(&r) {
                let depth = (h0[p] - h[p]) as f64;
                let phi = y.atan2(x);
                re += depth * (8.0 * phi).cos();
                im += depth * (8.0 * phi).sin();
                sum += depth.abs();
            }
        }
        re.hypot(im) / sum
    }

    /// A cone erodes about as round with water spread over the lower neighbours as it is: the
    /// 8-fold harmonic of the erosion depth around it is under a third of what one steepest
    /// direction per sample (D8) leaves, which cuts along the eight directions.
    #[test]
    fn spread_flow_erodes_a_cone_round_where_d8_cuts_along_eight_directions() {
        let (d8, spread) = (eightfold_depth(0.0), eightfold_depth(16.0));
        println!("8-fold harmonic of the erosion depth: D8 {d8:.3}, spread below 16 samples {spread:.3}");
        assert!(spread < d8 / 3.0, "D8 {d8}, spread {spread}");
    }

    /// Spread flow loses no water: on a field of bumps every free sample's area (1 each)
    /// arrives at the outlets (the border), within 1e-4 of their count, and the areas are
    /// the same bits on a second run.
    #[test]
    fn spread_areas_deliver_all_water_to_the_outlets() {
        let n = 40;
        let mut filled = bumps(n);
        crate::world::drainage::fill_around(&mut filled, n, None, FLAT_GRADIENT_M);
        let border = |q: usize| q.is_multiple_of(n) || q % n == n - 1 || q / n == 0 || q / n == n - 1;
        let free: Vec<bool> = (0..n * n).map(|q| !border(q)).collect();
        let (mut drops, mut receiver) = (vec![0f32; 8 * n * n], vec![NONE; n * n]);
        flow_directions(&filled, &free, &mut drops, &mut receiver, &mut vec![1f32; n * n]);
        let run = |spread_below: f32| {
            let mut area: Vec<f32> = free.iter().map(|&f| if f { 1.0 } else { 0.0 }).collect();
            spread_areas(&filled, &drops, &free, &receiver, spread_below, &mut Vec::new(), &mut area);
            area
        };
        for spread_below in [4.0, 1e9] {
            let area = run(spread_below);
            let out: f64 = (0..n * n).filter(|&q| border(q)).map(|q| area[q] as f64).sum();
            let want = free.iter().filter(|&&f| f).count() as f64;
            assert!((out - want).abs() < 1e-4 * want, "spread below {spread_below}: {out} of {want} arrive");
            assert_eq!(area, run(spread_below));
        }
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
