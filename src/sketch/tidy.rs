//! Tidying a made sketch (a VAE variant or blend) into one a person could have drawn: changed
//! parts rounded to brush-sized blobs, no band islands smaller than a brush dot, a strip of the
//! band between where two bands that are not neighbours meet, and no stroke specks — unless the
//! sketch it was made from has exactly that region, border or stroke.
//!
//! The VAE's edit ([`crate::models::sketch_vae::edit`]) rounds a soft change per pixel, and so
//! leaves specks: islands of another band a few pixels wide, borders of bands two apart and
//! stray stroke pixels. The generator raises a spike, a cliff or a pit on each (issue 35:
//! neighbour steps of 66 on the 0–255 scale where the targets' largest is 7).

use super::regions::{Components, neighbours};
use super::{SKETCH_PX, Sketch};

/// The smallest band region a made sketch keeps (pixels): the area of a dot of the canvas's
/// default 12 px brush (π·6² ≈ 113 px). Smaller regions are kept only where a source sketch
/// has exactly that region.
pub const MIN_REGION_PX: usize = 113;
/// The smallest ridge or valley stroke a made sketch keeps (pixels, 8-connected): a stroke
/// [`super::STROKE_PX`] wide and 6 px long. Smaller strokes are kept only where a source
/// sketch drew every pixel of them.
pub const MIN_STROKE_PX: usize = 18;

/// The ridge (or valley) mask of `s`.
fn strokes_of(s: &Sketch, ridge: bool) -> &[bool] {
    if ridge { &s.ridge } else { &s.valley }
}

/// Band regions (4-connected pixels of one band) smaller than `below_px` pixels.
pub fn band_islands(s: &Sketch, below_px: usize) -> usize {
    Components::of_bands(s).size.iter().filter(|&&c| c < below_px).count()
}

/// Merges every band island of `out` smaller than [`MIN_REGION_PX`] that is not a whole region
/// of a source into the band it borders most, until none is left: each pass merges every
/// small island into a neighbour, so the number of regions falls.
pub(super) fn merge_islands(out: &mut Sketch, sources: &[&Sketch], source_bands: &[Components]) {
    loop {
        let regions = Components::of_bands(out);
        let mut small: Vec<Vec<usize>> = regions
            .members()
            .into_iter()
            .filter(|m| m.len() < MIN_REGION_PX && !sources.iter().zip(source_bands).any(|(s, c)| s.band[m[0]] == out.band[m[0]] && c.is_whole(m)))
            .collect();
        if small.is_empty() {
            return;
        }
        small.sort_by_key(|m| (m.len(), m[0]));
        for m in &small {
            let own = out.band[m[0]];
            let mut contacts = [0usize; super::BANDS];
            for &p in m {
                for q in neighbours(p, false) {
                    if regions.label[q] != regions.label[p] {
                        contacts[out.band[q] as usize] += 1;
                    }
                }
            }
            // No contact at all only for a region covering the whole sketch: not small.
            let best = (0..super::BANDS as u8)
                .filter(|&b| contacts[b as usize] > 0)
                .max_by_key(|&b| (contacts[b as usize], std::cmp::Reverse(b.abs_diff(own)), std::cmp::Reverse(b)))
                .unwrap_or(own);
            for &p in m {
                out.band[p] = best;
            }
        }
    }
}

/// Radius of the disc [`round_changes`] takes the most common band over (pixels).
pub const ROUND_RADIUS_PX: i64 = 6;

/// Every pixel whose band no source has there takes the most common band in the disc of
/// [`ROUND_RADIUS_PX`] around it (ties: its own, then the lower), twice: changed parts become
/// blobs, as a brush draws them, instead of ragged strips a few pixels wide. Pixels a source
/// has keep their band.
fn round_changes(out: &mut Sketch, sources: &[&Sketch]) {
    let n = SKETCH_PX as i64;
    let r = ROUND_RADIUS_PX;
    let changed: Vec<usize> = (0..SKETCH_PX * SKETCH_PX).filter(|&p| !sources.iter().any(|s| s.band[p] == out.band[p])).collect();
    for _ in 0..2 {
        let band = out.band.clone();
        for &p in &changed {
            let (y, x) = ((p / SKETCH_PX) as i64, (p % SKETCH_PX) as i64);
            let mut count = [0usize; super::BANDS];
            for dy in -r..=r {
                for dx in -r..=r {
                    let (yy, xx) = (y + dy, x + dx);
                    if dy * dy + dx * dx <= r * r && yy >= 0 && xx >= 0 && yy < n && xx < n {
                        count[band[(yy * n + xx) as usize] as usize] += 1;
                    }
                }
            }
            let own = band[p];
            out.band[p] = (0..super::BANDS as u8).max_by_key(|&b| (count[b as usize], b == own, std::cmp::Reverse(b))).unwrap_or(own);
        }
    }
}

/// Width of the strip of the band between that [`widen_jumps`] puts where two bands that are
/// not next to each other meet or come closer than it (pixels): the canvas's default brush.
pub const JUMP_STRIP_PX: usize = 12;

/// Where band ≤ k and band ≥ k + 2 (k = 0, then 1) meet, or come closer than
/// [`JUMP_STRIP_PX`] across a narrower strip of band k + 1, the strip is widened to
/// [`JUMP_STRIP_PX`], half on each side: a pixel of either becomes band k + 1 when its steps
/// (4-connected) to the nearest pixel of another band and to the nearest of the far band add
/// up to at most [`JUMP_STRIP_PX`] + 1 (a pixel on a border two bands apart: 1 + 1; the 6th
/// pixel from it: 6 + 6). A pixel the sources have there stays as it is where the far band's
/// pixels near it are the sources' too. Rounds until nothing changes (bounded).
fn widen_jumps(out: &mut Sketch, sources: &[&Sketch]) {
    let n = SKETCH_PX * SKETCH_PX;
    let reach = JUMP_STRIP_PX + 1;
    // Steps (4-connected, up to `reach`; beyond it usize::MAX) from the nearest pixel for which
    // `from` holds.
    let distance = |from: &dyn Fn(usize) -> bool| {
        let mut dist = vec![usize::MAX; n];
        let mut queue = std::collections::VecDeque::new();
        for p in (0..n).filter(|&p| from(p)) {
            dist[p] = 0;
            queue.push_back(p);
        }
        while let Some(p) = queue.pop_front() {
            if dist[p] >= reach {
                continue;
            }
            for q in neighbours(p, false) {
                if dist[q] == usize::MAX {
                    dist[q] = dist[p] + 1;
                    queue.push_back(q);
                }
            }
        }
        dist
    };
    for _ in 0..4 {
        let mut any = false;
        for k in 0..super::BANDS as u8 - 2 {
            let (low, high) = (|b: u8| b <= k, |b: u8| b >= k + 2);
            let kept: Vec<bool> = (0..n).map(|p| sources.iter().any(|s| s.band[p] == out.band[p])).collect();
            let band = &out.band;
            let (to_high, to_low) = (distance(&|p| high(band[p])), distance(&|p| low(band[p])));
            let (to_new_high, to_new_low) = (distance(&|p| high(band[p]) && !kept[p]), distance(&|p| low(band[p]) && !kept[p]));
            let (off_low, off_high) = (distance(&|p| !low(band[p])), distance(&|p| !high(band[p])));
            let within = |a: usize, d: usize| a != usize::MAX && d != usize::MAX && a + d <= reach;
            let widen: Vec<usize> = (0..n)
                .filter(|&p| {
                    let (own, far, far_new) = if low(band[p]) {
                        (off_low[p], to_high[p], to_new_high[p])
                    } else if high(band[p]) {
                        (off_high[p], to_low[p], to_new_low[p])
                    } else {
                        return false;
                    };
                    within(own, far_new) || (!kept[p] && within(own, far))
                })
                .collect();
            if widen.is_empty() {
                continue;
            }
            any = true;
            widen.into_iter().for_each(|p| out.band[p] = k + 1);
        }
        if !any {
            return;
        }
    }
}

/// `made` as a person could have drawn it, in this order:
/// - every pixel whose band no source has takes the most common band around it
///   ([`round_changes`]);
/// - every band island smaller than [`MIN_REGION_PX`] merged into the band it borders most
///   (ties: the band nearest its own, then the lower), then where two bands that are not next
///   to each other meet (0 and 2, 1 and 3, 0 and 3: a cliff of half the relief in the
///   terrain), a strip of the band between, [`JUMP_STRIP_PX`] wide, half on each side
///   ([`widen_jumps`]); both again until neither changes anything;
/// - every ridge or valley component smaller than [`MIN_STROKE_PX`] dropped.
///
/// What one of the `sources` (the sketches `made` came from) has — exactly a whole region, the
/// same two bands on both sides of a border, a stroke every pixel of which it drew — stays as
/// it is. A sketch with nothing to tidy comes back unchanged.
pub fn tidy(made: &Sketch, sources: &[&Sketch]) -> Sketch {
    let mut out = made.clone();
    let source_bands: Vec<Components> = sources.iter().map(|s| Components::of_bands(s)).collect();
    round_changes(&mut out, sources);
    // Islands first (a speck must not be widened into a ring), then jumps; widening a jump
    // can leave an island, and merging an island can make a jump: both until neither changes
    // anything (a few rounds; bounded in case they ever trade pixels).
    for _ in 0..8 {
        let before = out.band.clone();
        merge_islands(&mut out, sources, &source_bands);
        widen_jumps(&mut out, sources);
        if out.band == before {
            break;
        }
    }
    // A short stroke stays where a source drew every pixel of it (a blend halfway may show a
    // drawn stroke in pieces); one with a pixel no source drew is a speck.
    for ridge in [true, false] {
        let mask = strokes_of(&out, ridge).to_vec();
        let mut keep = mask.clone();
        for m in Components::of_mask(&mask).members().into_iter().filter(|m| m.len() < MIN_STROKE_PX) {
            if !sources.iter().any(|s| m.iter().all(|&p| strokes_of(s, ridge)[p])) {
                m.iter().for_each(|&p| keep[p] = false);
            }
        }
        if ridge {
            out.ridge = keep;
        } else {
            out.valley = keep;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pixels whose band differs.
    fn differ(a: &Sketch, b: &Sketch) -> usize {
        a.band.iter().zip(&b.band).filter(|(x, y)| x != y).count()
    }

    /// Band 1 everywhere, band 3 in the square of side `side` at (y0, x0).
    fn square(y0: usize, x0: usize, side: usize) -> Sketch {
        let mut s = Sketch::filled(1);
        for y in y0..y0 + side {
            for x in x0..x0 + side {
                s.band[y * SKETCH_PX + x] = 3;
            }
        }
        s
    }

    /// [`merge_islands`] with the sources' regions.
    fn merged(s: &Sketch, sources: &[&Sketch]) -> Sketch {
        let mut out = s.clone();
        merge_islands(&mut out, sources, &sources.iter().map(|s| Components::of_bands(s)).collect::<Vec<_>>());
        out
    }

    #[test]
    fn an_island_under_113_px_joins_the_band_around_it_and_one_of_121_px_stays() {
        let small = square(40, 40, 10);
        assert_eq!(band_islands(&small, MIN_REGION_PX), 1);
        let t = merged(&small, &[&Sketch::filled(1)]);
        assert_eq!(differ(&t, &Sketch::filled(1)), 0);
        assert_eq!(band_islands(&t, MIN_REGION_PX), 0);
        let big = square(40, 40, 11);
        assert_eq!(differ(&merged(&big, &[&Sketch::filled(1)]), &big), 0);
        // Whole, the tidy merges it too: the rounding takes its corners first.
        assert_eq!(differ(&tidy(&small, &[&Sketch::filled(1)]), &Sketch::filled(1)), 0);
    }

    #[test]
    fn an_island_the_source_has_exactly_stays_and_a_fragment_of_a_source_region_goes() {
        let s = square(40, 40, 5);
        assert_eq!(differ(&tidy(&s, &[&s]), &s), 0, "the source's own 25 px island");
        // A 5 × 5 piece of a 20 × 20 source region, the rest of it band 1 now: a fragment.
        let source = square(40, 40, 20);
        assert_eq!(differ(&merged(&s, &[&source]), &Sketch::filled(1)), 0);
        assert_eq!(differ(&tidy(&s, &[&source]), &Sketch::filled(1)), 0);
    }

    #[test]
    fn an_island_joins_the_band_it_borders_most() {
        // Band 0 on the left half, band 2 on the right; a 4 × 4 island of band 3 with 3 of its
        // 4 columns in the right half.
        let mut s = halves(0, 2);
        for y in 60..64 {
            for x in 127..131 {
                s.band[y * SKETCH_PX + x] = 3;
            }
        }
        let t = merged(&s, &[]);
        assert_eq!(t.band[61 * SKETCH_PX + 127], 2);
        assert_eq!(band_islands(&t, MIN_REGION_PX), 0);
        assert_eq!((0..SKETCH_PX * SKETCH_PX).filter(|&p| t.band[p] == 3).count(), 0);
    }

    /// Band `left` in columns 0–127, band `right` in 128–255.
    fn halves(left: u8, right: u8) -> Sketch {
        let mut s = Sketch::filled(left);
        for p in 0..SKETCH_PX * SKETCH_PX {
            if p % SKETCH_PX >= 128 {
                s.band[p] = right;
            }
        }
        s
    }

    /// Pairs of 4-neighbours whose bands differ by 2 or more.
    fn jumps(s: &Sketch) -> usize {
        (0..SKETCH_PX * SKETCH_PX).map(|p| neighbours(p, false).filter(|&q| s.band[p].abs_diff(s.band[q]) >= 2).count()).sum()
    }

    #[test]
    fn where_band_0_meets_band_2_a_12_px_strip_of_band_1_is_put_half_on_each_side_unless_the_source_has_that_border_and_0_against_3_gets_12_px_of_1_and_of_2() {
        let s = halves(0, 2);
        assert_eq!(jumps(&s), 2 * SKETCH_PX);
        let t = tidy(&s, &[&Sketch::filled(0)]);
        assert_eq!(jumps(&t), 0);
        for y in [0, 100, 255] {
            let row: Vec<u8> = (118..138).map(|x| t.band[y * SKETCH_PX + x]).collect();
            assert_eq!(row, [vec![0u8; 4], vec![1; 12], vec![2; 4]].concat(), "row {y}");
        }
        assert_eq!(differ(&tidy(&s, &[&s]), &s), 0, "the source's own border");
        // Band 0 against band 3: a strip of 1 and one of 2, each 12 px wide.
        let t = tidy(&halves(0, 3), &[&Sketch::filled(0)]);
        assert_eq!(jumps(&t), 0);
        let row: Vec<u8> = (100..160).map(|x| t.band[50 * SKETCH_PX + x]).collect();
        let count = |b: u8| row.iter().filter(|&&v| v == b).count();
        assert_eq!((count(1), count(2)), (12, 12), "{row:?}");
        assert!(row.windows(2).all(|w| w[0] <= w[1]), "{row:?}");
    }

    /// Band 1 and band 3 with a strip of band 2 only 2 px wide between them, where the source
    /// has a 16 px strip of band 2 (a variant's edit narrowed the band between to a cliff):
    /// the strip becomes 12 px wide, 5 px taken from each side; where the source has the
    /// narrow strip too it stays 2 px.
    #[test]
    fn a_strip_of_the_band_between_2_px_wide_is_widened_to_12_px_unless_the_source_has_it() {
        let strip = |x0: usize, x1: usize| {
            let mut s = halves(1, 3);
            for y in 0..SKETCH_PX {
                (x0..x1).for_each(|x| s.band[y * SKETCH_PX + x] = 2);
            }
            s
        };
        let (s, source) = (strip(127, 129), strip(120, 136));
        assert_eq!(jumps(&s), 0, "no two bands apart touch");
        let t = tidy(&s, &[&source]);
        for y in [0, 100, 255] {
            let row: Vec<u8> = (118..138).map(|x| t.band[y * SKETCH_PX + x]).collect();
            assert_eq!(row, [vec![1u8; 4], vec![2; 12], vec![3; 4]].concat(), "row {y}");
        }
        assert_eq!(differ(&tidy(&s, &[&s]), &s), 0, "the source's own strip");
    }

    #[test]
    fn a_changed_strip_3_px_wide_is_rounded_away_and_a_changed_30_px_square_keeps_its_middle() {
        // Band 2 on band 1 (bands next to each other: no strip between them).
        let source = Sketch::filled(1);
        let mut s = Sketch::filled(1);
        for y in 20..23 {
            for x in 20..120 {
                s.band[y * SKETCH_PX + x] = 2;
            }
        }
        for y in 100..130 {
            for x in 100..130 {
                s.band[y * SKETCH_PX + x] = 2;
            }
        }
        let t = tidy(&s, &[&source]);
        assert!((20..23).all(|y| (20..120).all(|x| t.band[y * SKETCH_PX + x] == 1)), "the strip");
        assert_eq!(t.band[115 * SKETCH_PX + 115], 2);
        let kept = t.band.iter().filter(|&&b| b == 2).count();
        assert!((800..900).contains(&kept), "{kept} px of the square");
        assert_eq!(differ(&tidy(&s, &[&s]), &s), 0, "unchanged where the source has it");
    }

    #[test]
    fn a_stroke_speck_under_18_px_is_dropped_and_a_longer_one_or_a_piece_of_a_sources_stroke_kept() {
        let mut s = Sketch::filled(1);
        // A 3 × 5 ridge speck (15 px), a 3 × 40 ridge (120 px), a 2 × 2 valley dot.
        for y in 10..13 {
            for x in 10..15 {
                s.ridge[y * SKETCH_PX + x] = true;
            }
            for x in 100..140 {
                s.ridge[y * SKETCH_PX + x] = true;
            }
        }
        for y in 200..202 {
            for x in 200..202 {
                s.valley[y * SKETCH_PX + x] = true;
            }
        }
        let t = tidy(&s, &[&Sketch::filled(1)]);
        assert_eq!(t.ridge.iter().filter(|&&r| r).count(), 120);
        assert!(!t.ridge[11 * SKETCH_PX + 12] && t.ridge[11 * SKETCH_PX + 120]);
        assert_eq!(t.valley.iter().filter(|&&v| v).count(), 0);
        let kept = tidy(&s, &[&s]);
        assert_eq!((kept.ridge.iter().filter(|&&r| r).count(), kept.valley.iter().filter(|&&v| v).count()), (135, 4));
        // A 3 × 4 piece of the source's 3 × 40 ridge stays; the same piece 1 px off its line goes.
        let mut piece = Sketch::filled(1);
        for y in 10..13 {
            for x in 110..114 {
                piece.ridge[y * SKETCH_PX + x] = true;
            }
        }
        assert_eq!(tidy(&piece, &[&s]).ridge.iter().filter(|&&r| r).count(), 12);
        let mut off = Sketch::filled(1);
        for y in 11..14 {
            for x in 110..114 {
                off.ridge[y * SKETCH_PX + x] = true;
            }
        }
        assert_eq!(tidy(&off, &[&s]).ridge.iter().filter(|&&r| r).count(), 0);
    }
}
