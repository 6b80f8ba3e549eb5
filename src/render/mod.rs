//! Rendering: camera and controls, node meshes, and the wgpu renderer (WGSL in `shaders/`).

pub mod camera;
pub mod gpu;
pub mod mesh;
pub mod resident;

pub use camera::{Camera, CameraController, CameraMode, ControlInput};
pub use gpu::{FrameParams, RenderStats, TerrainRenderer};
