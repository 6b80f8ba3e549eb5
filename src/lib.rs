//! Terrain: an endless world grown around the camera, drawn with a per-tile quadtree level of
//! detail, shared by link. The same core runs in the page (wasm + WebGPU) and natively (CLI
//! and tests).
//!
//! Data flows one way: seed → tile ([`world`]) → quadtree node ([`world::quadtree`]) → GPU
//! buffer ([`render`]) → frame. [`app`] drives it per frame, [`ui`] draws the overlay,
//! [`share`] reads and writes links, [`dem`] reads and writes heightfields, [`models`] hosts
//! the neural networks and their runtime, `enhance` refines whole DEMs (native), [`geomorph`]
//! measures how terrain-like a heightfield is, [`queue`] tracks work in flight (epochs and
//! budgets), [`jobs`] runs it on a device, a worker or a thread, [`grid`] holds the tile
//! coordinates and the order-free schedule, [`sketch`] reads, draws and extracts the sketches that sketch-to-terrain turns into
//! a world ([`world::sketched`]).

#![warn(missing_docs)]

pub mod app;
pub mod dem;
#[cfg(not(target_arch = "wasm32"))]
pub mod enhance;
pub mod geomorph;
pub mod grid;
pub mod jobs;
pub mod models;
pub mod queue;
pub mod render;
pub mod share;
pub mod sketch;
#[cfg(all(feature = "train", not(target_arch = "wasm32")))]
pub mod train;
pub mod ui;
pub mod world;

#[cfg(target_arch = "wasm32")]
mod web;

/// Polls `f` to its end on this thread, natively: the tests' executor and
/// [`world::learned::LearnedModels::run_work`]'s (the native runners and native wgpu's
/// readback answer without waiting on anything else).
#[cfg(not(target_arch = "wasm32"))]
pub(crate) fn block_on<F: Future>(f: F) -> F::Output {
    let mut f = std::pin::pin!(f);
    let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
    loop {
        if let std::task::Poll::Ready(v) = f.as_mut().poll(&mut cx) {
            return v;
        }
    }
}

/// The repository's root directory as the tests and benches run: cargo's `CARGO_MANIFEST_DIR`
/// at run time, so a test binary built in one checkout and run from another (a moved clone
/// with a shared target directory) reads that checkout's `weights/` and fixtures; the directory
/// it was built in when run outside cargo.
#[cfg(not(target_arch = "wasm32"))]
#[doc(hidden)]
pub fn repo_root() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")), std::path::PathBuf::from)
}
