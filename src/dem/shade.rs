//! Hillshading: a heightfield as the grey picture of its relief lit from the north-west, the
//! way terrain is looked at from above (and how a world is compared with real ranges by eye).

use super::Heightfield;

/// Direction the light comes from, degrees clockwise from north.
pub const SUN_AZIMUTH_DEG: f64 = 315.0;
/// Height of the light above the horizon, degrees.
pub const SUN_ALTITUDE_DEG: f64 = 45.0;

impl Heightfield {
    /// The hillshade of the field: one grey byte per sample (row-major), 255 × the cosine of
    /// the angle between the surface's normal (central differences, true to the spacing) and
    /// the light from [`SUN_AZIMUTH_DEG`] at [`SUN_ALTITUDE_DEG`]; surfaces facing away are 0
    /// and missing samples (NaN) mid-grey.
    pub fn hillshade(&self) -> Vec<u8> {
        let (w, h) = (self.width, self.height);
        let (az, alt) = (SUN_AZIMUTH_DEG.to_radians(), SUN_ALTITUDE_DEG.to_radians());
        // The light's direction (x east, y south, z up).
        let light = [alt.cos() * az.sin(), -alt.cos() * az.cos(), alt.sin()];
        let at = |x: usize, y: usize| self.data[y * w + x] as f64;
        (0..w * h)
            .map(|p| {
                let (x, y) = (p % w, p / w);
                let (x0, x1, y0, y1) = (x.saturating_sub(1), (x + 1).min(w - 1), y.saturating_sub(1), (y + 1).min(h - 1));
                let dzdx = (at(x1, y) - at(x0, y)) / ((x1 - x0).max(1) as f64 * self.spacing_m);
                let dzdy = (at(x, y1) - at(x, y0)) / ((y1 - y0).max(1) as f64 * self.spacing_m);
                let norm = (dzdx * dzdx + dzdy * dzdy + 1.0).sqrt();
                let lit = (-dzdx * light[0] - dzdy * light[1] + light[2]) / norm;
                if lit.is_nan() { 128 } else { (lit.clamp(0.0, 1.0) * 255.0).round() as u8 }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Flat ground is lit at the sun's altitude (255 · sin 45° = 180); a slope facing the sun
    /// (rising to the south-east) is brighter than flat ground, one facing away darker.
    #[test]
    fn slopes_facing_the_sun_are_brighter_than_flat_ground_and_those_facing_away_darker() {
        let n = 8;
        let plane = |gx: f64, gy: f64| Heightfield::new(n, n, 10.0, (0..n * n).map(|p| ((p % n) as f64 * gx + (p / n) as f64 * gy) as f32 * 10.0).collect());
        let flat = plane(0.0, 0.0).hillshade();
        assert!(flat.iter().all(|&v| v == 180), "{flat:?}");
        let towards = plane(0.3, 0.3).hillshade()[n * n / 2];
        let away = plane(-0.3, -0.3).hillshade()[n * n / 2];
        assert!(towards > 180 && away < 180, "{towards} {away}");
        let mut hole = plane(0.0, 0.0);
        hole.data[0] = f32::NAN;
        assert_eq!(hole.hillshade()[0], 128);
    }
}
