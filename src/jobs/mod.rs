//! Jobs the core hands to whoever runs them (in the page: the WebGPU device or the CPU
//! worker; natively: a thread) — tiles of the learned world and TEM quads — and takes back.
//!
//! The bookkeeping of the jobs in flight is [`crate::queue`] (re-exported here): every job
//! carries the epoch of the world it was made for, and results for an older one are dropped.

pub mod calls;
pub mod gpu;
#[cfg(not(target_arch = "wasm32"))]
pub mod native;
pub mod protocol;
pub mod runner;

pub use crate::queue::{Job, JobQueue, JobStats, Outcome};
