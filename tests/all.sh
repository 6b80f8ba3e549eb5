#!/usr/bin/env bash
# Every test: formatting and clippy (native and wasm32), native unit, property and integration tests (world, schedule, LOD, links, DEM
# readers, CLI, burn on Vulkan/lavapipe, smoke trainings), the release build of the page with
# trunk, and the headless-Chromium end-to-end test of that page on WebGPU. Prints each step's
# time, the page's size and the e2e report.
set -euo pipefail
cd "$(dirname "$0")/.."
export PATH="$HOME/.cargo/bin:$PATH"
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/terrain-target}"
# burn's wgpu runtime natively: Vulkan through Mesa's software rasteriser.
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/xdg-$(id -u)}"; mkdir -p -m 700 "$XDG_RUNTIME_DIR"

t0=$(date +%s); last=$t0; report=""
step() { local now; now=$(date +%s); report+="$1 $((now - last)) s, "; echo "== $1: $((now - last)) s"; last=$now; }

bash tests/setup.sh system
# rustfmt, clippy and the page's target, before the page job (which would add the target too).
rustup component list --installed | grep -q '^clippy' || rustup component add clippy rustfmt
rustup target list --installed | grep -q wasm32-unknown-unknown || rustup target add wasm32-unknown-unknown
step "system packages"

# The page (its tools, wasm-bindgen-cli and trunk, then its release build) is made while the
# native tests build and run: each build alone leaves a core idle for long stretches on a
# 2-core machine. They share the target dir without waiting for each other: cargo locks
# target/debug for the tests and target/wasm32-unknown-unknown/page (Cargo.toml's [profile.page]) for the page.
mkdir -p "$CARGO_TARGET_DIR"
page_log="$CARGO_TARGET_DIR/page-build.log"
(
  p0=$(date +%s)
  bash tests/setup.sh tools
  p1=$(date +%s)
  trunk build --release
  echo "page job: tools $((p1 - p0)) s, trunk build $(( $(date +%s) - p1 )) s"
) > "$page_log" 2>&1 &
page_pid=$!

# Habits: the code is formatted (rustfmt.toml) and clippy-clean with warnings as errors, natively
# and for the page's wasm32 build.
cargo fmt --check
cargo clippy --all-targets -- -D warnings
cargo clippy --target wasm32-unknown-unknown --no-default-features --lib -- -D warnings
step "fmt and clippy"

cargo test --all-targets --no-run --timings
step "native build"
cargo test --all-targets
step "native tests"

# Coverage-guided fuzzing (libFuzzer) of the DEM readers, a bounded number of inputs.
bash fuzz/run.sh 300000
step "fuzz"

if ! wait "$page_pid"; then cat "$page_log"; echo "building the page failed" >&2; exit 1; fi
tail -1 "$page_log"
wasm=$(ls dist/*.wasm); js=$(ls dist/*.js)
raw=$(( $(stat -c %s "$wasm") + $(stat -c %s "$js") ))
gz=$(( $(gzip -9 -c "$wasm" | wc -c) + $(gzip -9 -c "$js" | wc -c) ))
wgz=0; for f in dist/weights/*.bpk; do wgz=$(( wgz + $(gzip -9 -c "$f" | wc -c) )); done
echo "page size: wasm+js $raw bytes raw, $gz bytes gzip; with all weights $(( gz + wgz )) bytes gzip"
step "page build (waited for)"

# The page in Chromium, then the CLI's exports read by the Khronos glTF validator and trimesh.
(cd tests/e2e && node --test --test-concurrency=1 page.test.mjs export.test.mjs)
step "e2e"
echo "timings: ${report}total $(( $(date +%s) - t0 )) s"
