//! The sun's shadow maps: two cascades, each an orthographic view from the sun over one slice
//! of the camera's view (the near slice in fine texels, the rest of the view in coarse ones),
//! with the terrain drawn into them as depth. The terrain pass compares each pixel's depth from
//! the sun with them. A shadow map, not per-tile horizon maps: it shadows whatever is drawn
//! (learned, procedural, sketch and pinned terrain, every level of detail) with no work per
//! tile on the CPU, and follows the sun wherever it is.

use glam::{Mat4, Vec3};

use super::camera::Camera;

/// Cascades of the shadow map.
pub const CASCADES: usize = 2;

/// Texels along each side of a cascade.
pub const SHADOW_MAP_PX: u32 = 1024;

/// How far (metres) beyond a cascade's slice, towards the sun, terrain still casts into it:
/// a 5 km high range's shadow at the sun's 26° reaches ~10 km.
pub const CASTER_REACH_M: f32 = 12_000.0;

/// The near cascade ends at this fraction of the shadowed distance, at least
/// [`NEAR_CASCADE_MIN_M`].
pub const NEAR_CASCADE_SHARE: f32 = 0.1;

/// Least far end of the near cascade (metres).
pub const NEAR_CASCADE_MIN_M: f32 = 1_500.0;

/// One cascade: the camera-relative sun view-projection (x, y in ±1, depth 0 at the sun's end
/// of its range and 1 at the other) and its metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cascade {
    /// Camera-relative metres to the cascade's clip space.
    pub view_proj: Mat4,
    /// Distance from the eye (metres) where the cascade's slice of the view ends.
    pub far_m: f32,
    /// Metres of ground a texel covers.
    pub texel_m: f32,
}

/// The cascades for camera `cam` at aspect `aspect` (width / height), sun direction `sun`
/// (unit, towards the sun), shadows out to `shadow_far_m` metres from the eye. Each cascade
/// encloses its slice's bounding sphere, its centre snapped to whole texels in the sun's
/// view so the shadows do not shimmer as the camera moves.
pub fn cascades(cam: &Camera, aspect: f32, sun: Vec3, shadow_far_m: f32) -> [Cascade; CASCADES] {
    let sun = sun.normalize();
    let far = shadow_far_m.max(NEAR_CASCADE_MIN_M * 2.0);
    let split = (far * NEAR_CASCADE_SHARE).max(NEAR_CASCADE_MIN_M);
    let slices = [(cam.near_m, split), (split * 0.9, far)];
    let fwd = cam.forward();
    let right = fwd.cross(Vec3::Y).normalize_or(cam.right());
    let up = right.cross(fwd);
    let ty = (cam.fov_y * 0.5).tan();
    let tx = ty * aspect;
    // The sun's view: looking along −sun, with an up that is never parallel to it.
    let light_up = if sun.y.abs() > 0.99 { Vec3::Z } else { Vec3::Y };
    let light_view = Mat4::look_to_rh(Vec3::ZERO, -sun, light_up);
    slices.map(|(n, f)| {
        let corners = [n, f].into_iter().flat_map(|d| [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)].map(|(sx, sy)| (fwd + right * (sx * tx) + up * (sy * ty)) * d));
        let corners: Vec<Vec3> = corners.collect();
        let centre = corners.iter().copied().sum::<Vec3>() / corners.len() as f32;
        let radius = corners.iter().map(|c| c.distance(centre)).fold(0.0, f32::max);
        let texel = 2.0 * radius / SHADOW_MAP_PX as f32;
        let c = light_view.transform_point3(centre);
        // The centre on whole texels of the world (not of the eye-relative frame, which moves
        // with the eye), so the map moves by whole texels as the camera moves.
        let eye = light_view.as_dmat4().transform_vector3(cam.position_m);
        let snap = |rel: f32, eye: f64| (((rel as f64 + eye) / texel as f64).round() * texel as f64 - eye) as f32;
        let (cx, cy) = (snap(c.x, eye.x), snap(c.y, eye.y));
        // Right-handed: the view looks along −z; nearest the sun is the largest z.
        let (z_near, z_far) = (-(c.z + radius + CASTER_REACH_M), -(c.z - radius));
        let proj = Mat4::orthographic_rh(cx - radius, cx + radius, cy - radius, cy + radius, z_near, z_far);
        Cascade { view_proj: proj * light_view, far_m: f, texel_m: texel }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    fn camera(pitch: f32) -> Camera {
        Camera { position_m: DVec3::new(5_000.0, 2_900.0, 7_000.0), yaw: 0.6, pitch, ..Camera::default() }
    }

    /// For a camera looking slightly down or steeply down, every corner of each cascade's
    /// slice of the view lands inside that cascade (x and y within ±1, depth within 0..1),
    /// and so does a point 10 km towards the sun from the slice's centre (a caster outside
    /// the view); the near cascade's texels are finer than the far one's.
    #[test]
    fn each_cascade_holds_its_slice_of_the_view_and_the_casters_towards_the_sun() {
        let sun = crate::render::gpu::sun_direction(2.3, crate::app::SUN_ELEVATION);
        for pitch in [-0.3, -1.2] {
            let cam = camera(pitch);
            let cs = cascades(&cam, 1.6, sun, 30_000.0);
            assert!(cs[0].texel_m < cs[1].texel_m, "{cs:?}");
            let mut near = cam.near_m;
            for c in cs {
                let inv = cam.view_proj(1.6).inverse();
                // The slice's corners from the camera's clip space (reverse-Z: depth = near / d).
                for d in [near.max(cam.near_m), c.far_m] {
                    for (x, y) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
                        let p = inv.project_point3(Vec3::new(x, y, cam.near_m / d));
                        let q = c.view_proj.project_point3(p);
                        assert!(q.x.abs() <= 1.0 + 1e-4 && q.y.abs() <= 1.0 + 1e-4 && (-1e-4..=1.0 + 1e-4).contains(&q.z), "pitch {pitch}, d {d}: {q}");
                    }
                }
                let mid = cam.forward() * (near + c.far_m) * 0.5 + sun * 10_000.0;
                let q = c.view_proj.project_point3(mid);
                assert!((0.0..=1.0).contains(&q.z) && q.x.abs() <= 1.0 && q.y.abs() <= 1.0, "caster {q}");
                near = c.far_m * 0.9;
            }
        }
    }

    /// Moving the eye by a third of a texel moves a ground point's place in the near cascade
    /// by a whole number of texels (0 or 1), never a fraction: the map does not shimmer.
    #[test]
    fn a_cascade_moves_by_whole_texels() {
        let sun = crate::render::gpu::sun_direction(2.3, crate::app::SUN_ELEVATION);
        let cam = camera(-0.3);
        let a = cascades(&cam, 1.6, sun, 30_000.0)[0];
        let step = Vec3::new(a.texel_m / 3.0, 0.0, 0.0);
        let mut moved = cam;
        moved.position_m += step.as_dvec3();
        let b = cascades(&moved, 1.6, sun, 30_000.0)[0];
        let ground = Vec3::new(300.0, -2_000.0, -900.0);
        // The same world point, relative to each eye.
        let pa = a.view_proj.project_point3(ground);
        let pb = b.view_proj.project_point3(ground - step);
        let texels = (pb.truncate() - pa.truncate()) * (SHADOW_MAP_PX as f32 / 2.0);
        let frac = (texels - texels.round()).abs();
        assert!(a.texel_m == b.texel_m && frac.x < 0.02 && frac.y < 0.02, "{texels}");
    }
}
