#!/usr/bin/env bash
# Coverage-guided fuzzing of the DEM readers with libFuzzer: builds fuzz_targets/dem_readers.rs
# with coverage instrumentation (stable rustc flags, no sanitizer runtime: the readers are safe
# Rust, so the findings are panics and runaway memory) and runs RUNS inputs (default 20000)
# from the seed files in seeds/, under a 1 GiB RSS limit. Exits non-zero on a finding, which
# libFuzzer saves as crash-*/oom-* under the target dir's fuzz/findings/
set -euo pipefail
cd "$(dirname "$0")"
runs="${1:-20000}"
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/terrain-target}/fuzz"
export RUSTFLAGS="-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 -Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table -Cllvm-args=-sanitizer-coverage-trace-compares --cfg fuzzing -Cdebug-assertions -Coverflow-checks"
# An explicit --target keeps the flags off build scripts and proc macros (they run on the host
# without libFuzzer).
host=$(rustc -vV | sed -n 's/^host: //p')
cargo build --release --bin dem_readers --target "$host"
# The corpus grows from run to run on the same machine; findings are kept beside it.
corpus="$CARGO_TARGET_DIR/corpus"
findings="$CARGO_TARGET_DIR/findings"
mkdir -p "$corpus" "$findings"
"$CARGO_TARGET_DIR/$host/release/dem_readers" -runs="$runs" -max_len=65536 -rss_limit_mb=1024 -timeout=10 \
  -print_final_stats=1 -artifact_prefix="$findings/" "$corpus" seeds 2>&1 | grep -v '^"' | tail -25
