//! What each command does, grouped by what it drives; `main.rs` only wires arguments to them.

pub mod bench;
pub mod render;
pub mod sketch;
pub mod tem;
pub mod world;

/// Keeps a copy of the checkpoint's weight file `file` as `snapshots/{prefix}_{step:06}.bpk`
/// in the `checkpoint` folder (a trainer's `--snapshots`: every checkpoint's generator, to pick
/// one or average them afterwards).
#[cfg(feature = "train")]
pub(crate) fn keep_snapshot(checkpoint: &std::path::Path, file: &str, prefix: &str, step: usize) -> Result<(), String> {
    let dir = checkpoint.join("snapshots");
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let to = dir.join(format!("{prefix}_{step:06}.bpk"));
    std::fs::copy(checkpoint.join(file), &to).map_err(|e| format!("{}: {e}", to.display()))?;
    Ok(())
}
