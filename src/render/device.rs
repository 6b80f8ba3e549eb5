//! The GPU device the page draws with: opening it (the same code for the browser's WebGPU and
//! a native Vulkan adapter) and watching it for loss.

use std::sync::atomic::{AtomicU32, Ordering::SeqCst};

/// An opened adapter and device.
pub struct Opened {
    /// The instance it came from.
    pub instance: wgpu::Instance,
    /// The adapter.
    pub adapter: wgpu::Adapter,
    /// The device, with every feature of the adapter but mappable primary buffers, and the
    /// adapter's limits.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
}

/// Opens the high-performance adapter of `backends` and a device on it; the error says which
/// step failed.
pub async fn open(backends: wgpu::Backends) -> Result<Opened, String> {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = backends;
    let instance = wgpu::Instance::new(desc);
    let adapter = instance
        .request_adapter(&wgpu::RequestAdapterOptions { power_preference: wgpu::PowerPreference::HighPerformance, ..Default::default() })
        .await
        .map_err(|e| format!("no GPU adapter ({e})"))?;
    device_on(instance, adapter).await
}

/// A device on `adapter` (from `instance`) with every feature of the adapter but mappable
/// primary buffers, and the adapter's limits.
async fn device_on(instance: wgpu::Instance, adapter: wgpu::Adapter) -> Result<Opened, String> {
    let features = adapter.features().difference(wgpu::Features::MAPPABLE_PRIMARY_BUFFERS);
    let (device, queue) = adapter
        .request_device(&wgpu::DeviceDescriptor { label: Some("terrain"), required_features: features, required_limits: adapter.limits(), ..Default::default() })
        .await
        .map_err(|e| format!("Could not open the GPU device: {e}"))?;
    Ok(Opened { instance, adapter, device, queue })
}

/// Opens a WebGL2 adapter on `canvas` (wgpu's GL backend, for a browser without WebGPU) and a
/// device on it as [`open`] does. The adapter is bound to the canvas's WebGL2 context, which
/// the renderer's surface then shares; the error says which step failed.
#[cfg(target_arch = "wasm32")]
pub async fn open_webgl(canvas: &web_sys::HtmlCanvasElement) -> Result<Opened, String> {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::GL;
    let instance = wgpu::Instance::new(desc);
    let surface = instance.create_surface(wgpu::SurfaceTarget::Canvas(canvas.clone())).map_err(|e| format!("no WebGL2 context on the canvas ({e})"))?;
    let adapter = instance
        .request_adapter(&wgpu::RequestAdapterOptions { compatible_surface: Some(&surface), ..Default::default() })
        .await
        .map_err(|e| format!("no WebGL2 adapter ({e})"))?;
    device_on(instance, adapter).await
}

/// The page's devices one after the other, and the loss of the current one. The device-lost
/// callback (any thread) reports its device's generation; the next frame takes a loss of the
/// current device exactly once. A late report about an older device changes nothing.
#[derive(Debug, Default)]
pub struct DeviceWatch {
    current: AtomicU32,
    lost: AtomicU32,
    restarts: AtomicU32,
}

impl DeviceWatch {
    /// A watch before the first device.
    pub const fn new() -> Self {
        Self { current: AtomicU32::new(0), lost: AtomicU32::new(0), restarts: AtomicU32::new(0) }
    }

    /// A new device is current: its generation (1 for the first).
    pub fn new_device(&self) -> u32 {
        self.current.fetch_add(1, SeqCst) + 1
    }

    /// The device of `generation` was lost.
    pub fn lost(&self, generation: u32) {
        self.lost.store(generation, SeqCst);
    }

    /// Whether the current device was lost and this is the first to ask since (then the page
    /// starts again on a new device; a restart is counted).
    pub fn take_loss(&self) -> bool {
        let current = self.current.load(SeqCst);
        let taken = current != 0 && self.lost.compare_exchange(current, 0, SeqCst, SeqCst).is_ok();
        if taken {
            self.restarts.fetch_add(1, SeqCst);
        }
        taken
    }

    /// Devices replaced after a loss so far.
    pub fn restarts(&self) -> u32 {
        self.restarts.load(SeqCst)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::block_on;

    /// A loss of the current device is taken once (one restart); a late report about an older
    /// device after a new one is current is never taken; nothing is lost before a device.
    #[test]
    fn a_loss_of_the_current_device_is_taken_once_and_older_ones_never() {
        let w = DeviceWatch::new();
        w.lost(0);
        assert!(!w.take_loss(), "no device yet");
        let first = w.new_device();
        assert_eq!(first, 1);
        w.lost(first);
        assert!(w.take_loss());
        assert!(!w.take_loss(), "taken once");
        let second = w.new_device();
        w.lost(first);
        assert!(!w.take_loss(), "a late report about the first device");
        w.lost(second);
        assert!(w.take_loss());
        assert_eq!(w.restarts(), 2);
    }

    /// The native adapter (lavapipe here) opens like the browser's: a device with the
    /// adapter's limits.
    #[test]
    fn the_native_adapter_opens_a_device_with_its_limits() {
        let opened = block_on(open(wgpu::Backends::VULKAN)).expect("a Vulkan adapter (mesa-vulkan-drivers)");
        assert_eq!(opened.device.limits().max_buffer_size, opened.adapter.limits().max_buffer_size);
    }
}
