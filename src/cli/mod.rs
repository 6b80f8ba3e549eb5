//! What each command does, grouped by what it drives; `main.rs` only wires arguments to them.

pub mod bench;
pub mod sketch;
pub mod tem;
pub mod world;
