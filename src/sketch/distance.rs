//! Exact Euclidean distance transform (Felzenszwalb & Huttenlocher's lower envelope of
//! parabolas, one pass per axis): for every pixel, the distance in pixels to the nearest pixel
//! of a set.

/// Distance (pixels) from every pixel of a `w`×`h` grid to the nearest pixel where `inside` is
/// true; `f32::INFINITY` everywhere if the set is empty.
pub fn distance_to(inside: &[bool], w: usize, h: usize) -> Vec<f32> {
    const FAR: f32 = 1e20;
    let mut d: Vec<f32> = inside.iter().map(|&b| if b { 0.0 } else { FAR }).collect();
    let mut line = vec![0f32; w.max(h)];
    let mut out = vec![0f32; w.max(h)];
    let mut v = vec![0usize; w.max(h)];
    let mut z = vec![0f32; w.max(h) + 1];
    for x in 0..w {
        for y in 0..h {
            line[y] = d[y * w + x];
        }
        envelope(&line[..h], &mut out[..h], &mut v, &mut z);
        for y in 0..h {
            d[y * w + x] = out[y];
        }
    }
    for y in 0..h {
        line[..w].copy_from_slice(&d[y * w..(y + 1) * w]);
        envelope(&line[..w], &mut out[..w], &mut v, &mut z);
        d[y * w..(y + 1) * w].copy_from_slice(&out[..w]);
    }
    d.iter().map(|&s| if s >= FAR / 2.0 { f32::INFINITY } else { s.sqrt() }).collect()
}

/// Squared distance transform of one line of sampled costs `f` into `out`.
fn envelope(f: &[f32], out: &mut [f32], v: &mut [usize], z: &mut [f32]) {
    let n = f.len();
    let mut k = 0usize;
    v[0] = 0;
    z[0] = f32::NEG_INFINITY;
    z[1] = f32::INFINITY;
    let sq = |q: usize| (q * q) as f32;
    for q in 1..n {
        loop {
            let p = v[k];
            let s = ((f[q] + sq(q)) - (f[p] + sq(p))) / (2.0 * (q as f32 - p as f32));
            if s <= z[k] && k > 0 {
                k -= 1;
            } else {
                k += 1;
                v[k] = q;
                z[k] = s;
                z[k + 1] = f32::INFINITY;
                break;
            }
        }
    }
    k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while z[k + 1] < q as f32 {
            k += 1;
        }
        let p = v[k];
        let dq = q as f32 - p as f32;
        *o = dq * dq + f[p];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances_equal_brute_force_on_a_random_set() {
        let (w, h) = (37, 23);
        let inside: Vec<bool> = (0..w * h).map(|p| (p * 7919 + 13) % 31 == 0).collect();
        let d = distance_to(&inside, w, h);
        for y in 0..h {
            for x in 0..w {
                let best =
                    (0..w * h).filter(|&q| inside[q]).map(|q| (((q % w) as f32 - x as f32).powi(2) + ((q / w) as f32 - y as f32).powi(2)).sqrt()).fold(f32::INFINITY, f32::min);
                assert!((d[y * w + x] - best).abs() < 1e-3, "({x}, {y}): {} vs {best}", d[y * w + x]);
            }
        }
        assert!(distance_to(&[false; 12], 4, 3).iter().all(|v| v.is_infinite()));
    }
}
