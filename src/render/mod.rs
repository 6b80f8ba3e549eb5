//! Rendering: camera and controls, node meshes, and the wgpu renderer (WGSL in `shaders/`).

pub mod camera;
pub mod device;
pub mod gpu;
pub mod mesh;
pub mod pacing;
pub mod resident;
pub mod shadow;

pub use camera::{Camera, CameraController, CameraMode, ControlInput};
pub use gpu::{FrameParams, RenderStats, TargetEncoding, TerrainRenderer};
pub use pacing::FramePacer;

/// Fraction of the screen's resolution (per axis) at which the 3-D view is drawn on a
/// software adapter (SwiftShader, llvmpipe): those rasterise on the same CPU cores as the
/// page, and a quarter of the pixels is a quarter of their work. A hardware GPU draws at
/// full resolution.
pub const SOFTWARE_VIEW_SCALE: f32 = 0.5;

/// Bytes of one node mesh on the GPU (one slot of the renderer's mesh buffer).
pub const MESH_BYTES: u64 = (mesh::NODE_VERTICES * std::mem::size_of::<mesh::Vertex>()) as u64;

/// Most GPU memory the node meshes take on any device (bytes): 256 MiB, the largest buffer
/// every WebGPU device must offer.
pub const MESH_MEMORY_BUDGET: u64 = 256 << 20;

/// Slots of the mesh buffer on a device whose buffers may hold `max_buffer_size` bytes: the
/// buffer never exceeds that limit nor [`MESH_MEMORY_BUDGET`].
pub fn mesh_slots(max_buffer_size: u64) -> u32 {
    (max_buffer_size.min(MESH_MEMORY_BUDGET) / MESH_BYTES).min(u32::MAX as u64) as u32
}

/// Nodes a frame may draw on such a device: half the mesh slots, the other half keeping the
/// meshes of recent frames (turning back needs no uploads). Over it, the app raises its
/// effective LOD target until the view fits.
pub fn node_budget(max_buffer_size: u64) -> usize {
    mesh_slots(max_buffer_size) as usize / 2
}

/// Most pixels the 3-D view's target holds (2560 × 1600): a larger view (a 4K screen, a
/// phone's at ratio 3 held sideways) is drawn at the largest resolution under it.
pub const VIEW_MAX_PIXELS: u32 = 2560 * 1600;

/// Size (pixels) of the 3-D view's target for a view of `points` (egui points) at
/// `pixels_per_point`: at the render scale `scale` per axis where one is chosen, else at
/// [`SOFTWARE_VIEW_SCALE`] on a software adapter and at full resolution on others; scaled
/// down to at most [`VIEW_MAX_PIXELS`]; at least 1×1.
pub fn view_size(points: [f32; 2], pixels_per_point: f32, software_adapter: bool, scale: Option<f32>) -> [u32; 2] {
    let scale = pixels_per_point * scale.unwrap_or(if software_adapter { SOFTWARE_VIEW_SCALE } else { 1.0 });
    let full = points.map(|p| (p * scale).max(1.0));
    let cap = (VIEW_MAX_PIXELS as f32 / (full[0] * full[1])).sqrt().min(1.0);
    full.map(|p| if cap < 1.0 { (p * cap).floor() } else { p.round() }.max(1.0) as u32)
}

/// The pixels a canvas of `css_px` CSS pixels should hold at device pixel ratio `ratio`, when
/// its backing store `current` is more than a pixel off them on either axis (`None`: keep it;
/// the browser's own device-pixel size may differ from the rounded product by one). Headless
/// Chromium with an emulated ratio reports device-pixel sizes equal to the CSS size, which left
/// the page's UI drawn `ratio` times too large into a canvas of a `ratio`-th of the pixels.
pub fn canvas_backing(css_px: [f64; 2], ratio: f64, current: [u32; 2]) -> Option<[u32; 2]> {
    let want = css_px.map(|c| (c * ratio).round().max(1.0) as u32);
    let off = want.iter().zip(current).any(|(w, c)| w.abs_diff(c) > 1);
    off.then_some(want)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 960×600 CSS-pixel canvas at ratio 2 holding 960×600 pixels is made 1920×1200; one
    /// holding 1919×1200 (the browser's own rounding) is kept, as is 960×600 at ratio 1; a
    /// 390×844 canvas at ratio 3 is made 1170×2532.
    #[test]
    fn a_canvas_holds_its_css_size_times_the_pixel_ratio() {
        assert_eq!(canvas_backing([960.0, 600.0], 2.0, [960, 600]), Some([1920, 1200]));
        assert_eq!(canvas_backing([960.0, 600.0], 2.0, [1919, 1200]), None);
        assert_eq!(canvas_backing([960.0, 600.0], 1.0, [960, 600]), None);
        assert_eq!(canvas_backing([390.0, 844.0], 3.0, [390, 844]), Some([1170, 2532]));
    }

    /// A 1280×720-point view at 2 pixels per point is 2560×1440 pixels on a GPU and
    /// 1280×720 on a software adapter; an empty view is still 1×1; a chosen scale of 0.75
    /// holds on either; a 3840×2160 view is drawn at 2560×1600 pixels or fewer, the shape kept.
    #[test]
    fn view_size_is_halved_per_axis_on_software_adapters_scaled_when_chosen_and_capped() {
        assert_eq!(view_size([1280.0, 720.0], 2.0, false, None), [2560, 1440]);
        assert_eq!(view_size([1280.0, 720.0], 2.0, true, None), [1280, 720]);
        assert_eq!(view_size([0.0, 0.3], 1.0, true, None), [1, 1]);
        assert_eq!(view_size([1280.0, 720.0], 2.0, true, Some(0.75)), [1920, 1080]);
        assert_eq!(view_size([1280.0, 720.0], 2.0, false, Some(0.75)), [1920, 1080]);
        let [w, h] = view_size([1920.0, 1080.0], 2.0, false, None);
        assert!(w * h <= VIEW_MAX_PIXELS && w * h > VIEW_MAX_PIXELS * 99 / 100, "{w}×{h}");
        assert!((w as f32 / h as f32 - 16.0 / 9.0).abs() < 0.01, "{w}×{h}");
    }
}
