//! The camera (pose, projection, frustum for culling) and its controller (fly, orbit, touch),
//! which never lets the eye go below the ground.

use glam::{DVec3, Mat4, Vec2, Vec3};

use crate::world::quadtree::{Frustum, LodView};

/// Metres the eye always keeps above the highest ground within [`CLEARANCE_RADIUS_M`]: the
/// 32 m ground the controller knows, plus room for the learned detail drawn on it (a few
/// metres) and the near plane.
pub const MIN_CLEARANCE_M: f64 = 5.0;

/// Radius (metres) around the eye whose ground the eye keeps clear of: flying into a slope,
/// the eye rises before the slope fills the screen (it used to stop 3 m above the ground
/// under it, inside the slope ahead: a grey screen).
pub const CLEARANCE_RADIUS_M: f64 = 20.0;

/// A perspective camera in world metres (x east, y up, z south).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position (world metres).
    pub position_m: DVec3,
    /// Heading (radians; 0 looks towards −z, positive turns towards +x).
    pub yaw: f32,
    /// Pitch (radians; positive looks up), within ±1.55.
    pub pitch: f32,
    /// Vertical field of view (radians).
    pub fov_y: f32,
    /// Near plane distance (metres).
    pub near_m: f32,
    /// Distance beyond which nothing is drawn (metres); culling uses it as the far plane.
    pub far_m: f32,
}

impl Default for Camera {
    fn default() -> Self {
        Self { position_m: DVec3::new(0.0, 1500.0, 0.0), yaw: 0.0, pitch: -0.2, fov_y: 60f32.to_radians(), near_m: 1.0, far_m: 30_000.0 }
    }
}

impl Camera {
    /// Unit view direction.
    pub fn forward(&self) -> Vec3 {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        Vec3::new(sy * cp, sp, -cy * cp)
    }

    /// Unit horizontal right direction.
    pub fn right(&self) -> Vec3 {
        let (sy, cy) = self.yaw.sin_cos();
        Vec3::new(cy, 0.0, sy)
    }

    /// View matrix with the eye at the origin (camera-relative rendering keeps precision far
    /// from the world origin).
    pub fn view(&self) -> Mat4 {
        Mat4::look_to_rh(Vec3::ZERO, self.forward(), Vec3::Y)
    }

    /// Rendering projection: reverse-Z with an infinite far plane (depth 1 at the near plane,
    /// 0 at infinity), for even depth precision out to the horizon.
    pub fn projection(&self, aspect: f32) -> Mat4 {
        Mat4::perspective_infinite_reverse_rh(self.fov_y, aspect, self.near_m)
    }

    /// Camera-relative view-projection used to draw.
    pub fn view_proj(&self, aspect: f32) -> Mat4 {
        self.projection(aspect) * self.view()
    }

    /// The culling frustum (finite far plane at `far_m`).
    pub fn frustum(&self, aspect: f32) -> Frustum {
        Frustum::from_view_proj(Mat4::perspective_rh(self.fov_y, aspect, self.near_m, self.far_m) * self.view())
    }

    /// What node selection needs for a viewport `height_px` pixels tall with aspect `aspect`.
    pub fn lod_view(&self, aspect: f32, height_px: f32, target_px: f64, max_depth: u8) -> LodView {
        LodView { eye_m: self.position_m, frustum: self.frustum(aspect), pixels_per_radian: (height_px as f64 * 0.5) / (self.fov_y as f64 * 0.5).tan(), target_px, max_depth }
    }
}

/// How the camera moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraMode {
    /// Free flight: WASD/QE move, drag looks.
    Fly,
    /// Orbit around a point on the ground: drag turns, scroll/pinch zooms, WASD moves the point.
    Orbit,
}

/// One frame of user input, already mapped from keys, mouse and touch.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ControlInput {
    /// Movement intent: x right, y up, z forward, each in −1..1 (WASD/QE, two-finger drag).
    pub movement: Vec3,
    /// Look/turn drag this frame (pixels; mouse drag or one-finger drag).
    pub look_px: Vec2,
    /// Scroll this frame (lines; positive = away from the user): speed in fly, zoom in orbit.
    pub scroll: f32,
    /// Pinch zoom factor this frame (1 = none, > 1 = fingers apart).
    pub pinch: f32,
    /// Move faster while held (Shift).
    pub boost: bool,
}

/// Turns input into camera motion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraController {
    /// Current mode.
    pub mode: CameraMode,
    /// Flight speed (m/s).
    pub speed_mps: f64,
    /// Radians per pixel of drag.
    pub look_per_px: f32,
    /// Orbit centre (world metres).
    pub orbit_target_m: DVec3,
    /// Orbit distance from the centre (metres).
    pub orbit_distance_m: f64,
    /// The orbit's centre is where entering orbit put it (on the ground under the screen's
    /// centre, or in the air looking at the sky): it follows the ground once the user moves it.
    pub orbit_free: bool,
}

/// Steps of 50 m along the view ray searched for the orbit's pivot (50 km).
const ORBIT_SEARCH_STEPS: usize = 1000;

impl Default for CameraController {
    fn default() -> Self {
        Self { mode: CameraMode::Fly, speed_mps: 300.0, look_per_px: 0.004, orbit_target_m: DVec3::ZERO, orbit_distance_m: 3000.0, orbit_free: false }
    }
}

impl CameraController {
    /// Switches mode without moving the camera; entering orbit puts the pivot on the terrain
    /// under the screen's centre (`ground(x, z)`: its height, metres, `None` where unknown).
    pub fn set_mode(&mut self, mode: CameraMode, cam: &Camera, ground: impl Fn(f64, f64) -> Option<f32>) {
        if mode == CameraMode::Orbit && self.mode != CameraMode::Orbit {
            // The pivot is the terrain under the screen's centre, where the view ray first
            // meets the ground (50 m steps, then halved to 1 m); looking at the sky, a point on
            // the ray.
            let (eye, dir) = (cam.position_m, cam.forward().as_dvec3());
            let above = |t: f64| {
                let p = eye + dir * t;
                ground(p.x, p.z).is_none_or(|g| p.y > g as f64)
            };
            let hit = (1..=ORBIT_SEARCH_STEPS).map(|k| k as f64 * 50.0).find(|&t| !above(t)).map(|mut t| {
                let mut step = 25.0;
                while step >= 0.5 {
                    t += if above(t) { step } else { -step };
                    step *= 0.5;
                }
                t
            });
            self.orbit_distance_m = hit.unwrap_or(self.orbit_distance_m).clamp(50.0, 50_000.0);
            self.orbit_target_m = eye + dir * self.orbit_distance_m;
            // Not put on the ground (to the 1 m of the search) until the user moves it: entering
            // orbit never moves the camera.
            self.orbit_free = true;
        }
        self.mode = mode;
    }

    /// Applies `input` over `dt_s` seconds, then lifts the eye to at least [`MIN_CLEARANCE_M`]
    /// above the highest ground within [`CLEARANCE_RADIUS_M`] (a 9-point stencil of
    /// `ground(x, z)`: metres, `None` where unknown).
    pub fn update(&mut self, cam: &mut Camera, input: &ControlInput, dt_s: f64, ground: impl Fn(f64, f64) -> Option<f32>) {
        cam.yaw = (cam.yaw + input.look_px.x * self.look_per_px).rem_euclid(std::f32::consts::TAU);
        cam.pitch = (cam.pitch - input.look_px.y * self.look_per_px).clamp(-1.55, 1.55);
        let boost = if input.boost { 4.0 } else { 1.0 };
        match self.mode {
            CameraMode::Fly => {
                self.speed_mps = (self.speed_mps * 1.15f64.powf(input.scroll as f64)).clamp(5.0, 20_000.0);
                let zoom_move = if input.pinch > 0.0 { (input.pinch as f64).ln() * 2000.0 } else { 0.0 };
                let f = cam.forward().as_dvec3();
                let r = cam.right().as_dvec3();
                let m = input.movement.as_dvec3();
                let v = (f * m.z + r * m.x + DVec3::Y * m.y) * self.speed_mps * boost * dt_s + f * zoom_move;
                cam.position_m += v;
            }
            CameraMode::Orbit => {
                let mut zoom = 0.85f64.powf(input.scroll as f64);
                if input.pinch > 0.0 {
                    zoom /= input.pinch as f64;
                }
                self.orbit_distance_m = (self.orbit_distance_m * zoom).clamp(50.0, 50_000.0);
                let r = cam.right().as_dvec3();
                let flat = DVec3::new(r.z, 0.0, -r.x);
                let m = input.movement.as_dvec3();
                let step = self.orbit_distance_m * 0.8 * boost * dt_s;
                self.orbit_target_m += (r * m.x + flat * m.z + DVec3::Y * m.y) * step;
                self.orbit_free &= m == DVec3::ZERO;
                if !self.orbit_free
                    && let Some(g) = ground(self.orbit_target_m.x, self.orbit_target_m.z)
                {
                    self.orbit_target_m.y = g as f64;
                }
                cam.position_m = self.orbit_target_m - cam.forward().as_dvec3() * self.orbit_distance_m;
            }
        }
        let (x, z, r) = (cam.position_m.x, cam.position_m.z, CLEARANCE_RADIUS_M);
        let around = [(0.0, 0.0), (r, 0.0), (-r, 0.0), (0.0, r), (0.0, -r), (0.7 * r, 0.7 * r), (-0.7 * r, 0.7 * r), (0.7 * r, -0.7 * r), (-0.7 * r, -0.7 * r)];
        let highest = around.iter().filter_map(|&(dx, dz)| ground(x + dx, z + dz)).fold(f32::NEG_INFINITY, f32::max);
        if highest.is_finite() {
            cam.position_m.y = cam.position_m.y.max(highest as f64 + MIN_CLEARANCE_M);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forward_and_right_follow_yaw() {
        let mut c = Camera { pitch: 0.0, ..Camera::default() };
        assert!((c.forward() - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-6);
        c.yaw = std::f32::consts::FRAC_PI_2;
        assert!((c.forward() - Vec3::X).length() < 1e-6);
        assert!((c.right() - Vec3::Z).length() < 1e-6);
    }

    #[test]
    fn reverse_z_maps_near_to_one_and_far_towards_zero() {
        let c = Camera::default();
        let p = c.projection(1.0);
        let near = p * glam::Vec4::new(0.0, 0.0, -c.near_m, 1.0);
        let far = p * glam::Vec4::new(0.0, 0.0, -20_000.0, 1.0);
        assert!((near.z / near.w - 1.0).abs() < 1e-6);
        assert!(far.z / far.w > 0.0 && far.z / far.w < 1e-3);
    }

    #[test]
    fn the_eye_never_goes_below_the_ground() {
        let mut cam = Camera { position_m: DVec3::new(0.0, 100.0, 0.0), pitch: -1.5, ..Camera::default() };
        let mut ctl = CameraController::default();
        let dive = ControlInput { movement: Vec3::new(0.0, -1.0, 1.0), ..Default::default() };
        for _ in 0..100 {
            ctl.update(&mut cam, &dive, 0.1, |x, _| Some(50.0 + (x * 0.01).sin() as f32 * 40.0));
            let g = 50.0 + (cam.position_m.x * 0.01).sin() * 40.0;
            assert!(cam.position_m.y >= g + MIN_CLEARANCE_M - 1e-3, "{} below {}", cam.position_m.y, g);
        }
        ctl.set_mode(CameraMode::Orbit, &cam, |_, _| None);
        for _ in 0..50 {
            ctl.update(&mut cam, &ControlInput { look_px: Vec2::new(3.0, -8.0), scroll: 2.0, ..Default::default() }, 0.1, |_, _| Some(500.0));
            assert!(cam.position_m.y >= 500.0 + MIN_CLEARANCE_M - 1e-3);
        }
    }

    /// Switching from flying to orbiting leaves the camera where it was (to 1 mm): looking
    /// down at ground 100 m high, the pivot is the ground under the screen's centre (to 1 m)
    /// at the eye's distance to it; looking at the sky, a point on the view ray that stays
    /// in the air until the user moves it.
    #[test]
    fn entering_orbit_keeps_the_camera_and_pivots_on_the_ground_at_the_screen_centre() {
        let ground = |_: f64, _: f64| Some(100.0f32);
        for pitch in [-0.5f32, 0.3] {
            let mut cam = Camera { position_m: DVec3::new(10.0, 2000.0, -30.0), yaw: 0.7, pitch, ..Camera::default() };
            let before = cam.position_m;
            let mut ctl = CameraController::default();
            ctl.set_mode(CameraMode::Orbit, &cam, ground);
            for _ in 0..5 {
                ctl.update(&mut cam, &ControlInput::default(), 0.016, ground);
            }
            assert!((cam.position_m - before).length() < 1e-3, "pitch {pitch}: moved from {before} to {}", cam.position_m);
            let pivot = ctl.orbit_target_m;
            if pitch < 0.0 {
                assert!((pivot.y - 100.0).abs() < 1.0, "the pivot is at {pivot}");
                assert!(((pivot - before).length() - ctl.orbit_distance_m).abs() < 1e-3, "{} vs {}", (pivot - before).length(), ctl.orbit_distance_m);
                assert!(((pivot - before).normalize() - cam.forward().as_dvec3().normalize()).length() < 1e-6, "the pivot is on the view ray");
            } else {
                assert!(ctl.orbit_free && pivot.y > 2000.0, "a pivot in the air: {pivot}");
            }
        }
    }

    /// Flying into a 45° slope, the eye stays at least the clearance above the highest ground
    /// within 20 m (not only the ground under it), frame after frame.
    #[test]
    fn flying_into_a_slope_keeps_the_eye_clear_of_the_slope_ahead() {
        let slope = |x: f64, _: f64| Some(x.max(0.0) as f32);
        let mut cam = Camera { position_m: DVec3::new(-100.0, 10.0, 0.0), yaw: std::f32::consts::FRAC_PI_2, pitch: 0.0, ..Camera::default() };
        let mut ctl = CameraController::default();
        let ahead = ControlInput { movement: Vec3::new(0.0, 0.0, 1.0), boost: true, ..Default::default() };
        for _ in 0..40 {
            ctl.update(&mut cam, &ahead, 0.05, slope);
            let highest = (cam.position_m.x + CLEARANCE_RADIUS_M).max(0.0);
            assert!(cam.position_m.y >= highest + MIN_CLEARANCE_M - 1e-6, "eye at {} with ground {highest} m within 20 m", cam.position_m);
        }
        assert!(cam.position_m.x > 0.0, "it flew on, up the slope");
    }

    #[test]
    fn scroll_changes_speed_and_pinch_moves_forward() {
        let mut cam = Camera { pitch: 0.0, position_m: DVec3::new(0.0, 1000.0, 0.0), ..Camera::default() };
        let mut ctl = CameraController::default();
        let s0 = ctl.speed_mps;
        ctl.update(&mut cam, &ControlInput { scroll: 3.0, ..Default::default() }, 0.016, |_, _| None);
        assert!(ctl.speed_mps > s0 * 1.4);
        let z0 = cam.position_m.z;
        ctl.update(&mut cam, &ControlInput { pinch: 1.1, ..Default::default() }, 0.016, |_, _| None);
        assert!(cam.position_m.z < z0 - 100.0, "pinching out flies forward (−z)");
    }
}
