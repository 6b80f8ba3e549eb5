#!/usr/bin/env bash
# Every test: formatting and clippy (native and wasm32), native unit, property and integration
# tests (world, schedule, LOD, links, DEM readers, CLI, burn on Vulkan/lavapipe, smoke
# trainings), a bounded fuzzing run, the release build of the page (tools/page.sh), and the
# headless-Chromium end-to-end test of that page on WebGPU. Installs what it needs on a fresh
# machine; prints each step's time, the page's size and the e2e report. No test asserts this
# machine's speed (speed is `cargo bench`'s and tests/e2e/bench.mjs's).
set -euo pipefail
cd "$(dirname "$0")/.."
export PATH="${CARGO_HOME:-$HOME/.cargo}/bin:$HOME/.cargo/bin:$PATH"
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/terrain-target}"
# burn's wgpu runtime natively: Vulkan through Mesa's software rasteriser.
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/xdg-$(id -u)}"; mkdir -p -m 700 "$XDG_RUNTIME_DIR"
# Each build here is made once: incremental compilation state would only cost time and disk.
export CARGO_INCREMENTAL=0

t0=$(date +%s); last=$t0; report=""
step() { local now; now=$(date +%s); report+="$1 $((now - last)) s, "; echo "== $1: $((now - last)) s"; last=$now; }
mkdir -p "$CARGO_TARGET_DIR"

# Chromium, Mesa's Vulkan, the npm packages and trimesh download while the code compiles.
system_log="$CARGO_TARGET_DIR/system-setup.log"
bash tests/setup.sh system > "$system_log" 2>&1 &
system_pid=$!
# A step that fails ends the run: the jobs still running in the background end with it.
trap 'kill $(jobs -p) 2>/dev/null || true' EXIT
# rustfmt, clippy and the page's target, before the page job (which would add the target too).
rustup component list --installed | grep -q '^clippy' || rustup component add clippy rustfmt
rustup target list --installed | grep -q wasm32-unknown-unknown || rustup target add wasm32-unknown-unknown

# Habits: the code is formatted (rustfmt.toml) and clippy-clean with warnings as errors, natively
# and for the page's wasm32 build. Clippy runs as the compiler of this crate's own targets
# (RUSTC_WORKSPACE_WRAPPER; dependencies are compiled by rustc as always), so the tests' build
# and the page's build are the lint too: no separate check-mode build of every dependency for
# clippy, natively and for wasm32. CLIPPY_ARGS is how `cargo clippy -- -D warnings` hands the
# flag to clippy-driver.
cargo fmt --check
export RUSTC_WORKSPACE_WRAPPER
RUSTC_WORKSPACE_WRAPPER="$(command -v clippy-driver)"
export CLIPPY_ARGS="-D__CLIPPY_HACKERY__warnings__CLIPPY_HACKERY__"
step "setup and fmt"

# The page (wasm-bindgen-cli, then its release build, linted by clippy for wasm32) is made
# while the native tests build and run: each build alone leaves a core idle for long
# stretches on a 2-core machine. They share the target dir without waiting for each other:
# cargo locks target/debug for the tests and target/wasm32-unknown-unknown/page (Cargo.toml's
# [profile.page]) for the page.
page_log="$CARGO_TARGET_DIR/page-build.log"
(
  p0=$(date +%s)
  bash tests/setup.sh tools
  p1=$(date +%s)
  bash tools/page.sh build
  echo "page job: tools $((p1 - p0)) s, page build and wasm32 clippy $(( $(date +%s) - p1 )) s"
) > "$page_log" 2>&1 &
page_pid=$!

cargo test --all-targets --no-run --timings
step "native build and clippy"

# The native tests and the fuzzing run beside the e2e: no test asserts speed, so a shared
# machine only makes each slower, and each alone leaves a core idle for long stretches (the
# e2e's waits on timers and the browser, the test harness's last long tests).
native_log="$CARGO_TARGET_DIR/native-tests.log"
(
  n0=$(date +%s)
  cargo test --all-targets
  n1=$(date +%s)
  # Coverage-guided fuzzing (libFuzzer) of the DEM readers, a bounded number of inputs (its
  # own build, without clippy).
  env -u RUSTC_WORKSPACE_WRAPPER -u CLIPPY_ARGS bash fuzz/run.sh 300000
  echo "native job: tests $((n1 - n0)) s, fuzz $(( $(date +%s) - n1 )) s"
) > "$native_log" 2>&1 &
native_pid=$!

if ! wait "$page_pid"; then cat "$page_log"; echo "building the page failed" >&2; exit 1; fi
tail -1 "$page_log"
wasm=$(ls dist/*.wasm); js=$(ls dist/*.js)
raw=$(( $(stat -c %s "$wasm") + $(stat -c %s "$js") ))
gz=$(( $(gzip -9 -c "$wasm" | wc -c) + $(gzip -9 -c "$js" | wc -c) ))
wgz=0; for f in dist/weights/*.bpk; do wgz=$(( wgz + $(gzip -9 -c "$f" | wc -c) )); done
echo "page size: wasm+js $raw bytes raw, $gz bytes gzip; with all weights $(( gz + wgz )) bytes gzip"
if ! wait "$system_pid"; then cat "$system_log"; echo "installing the system packages failed" >&2; exit 1; fi
step "page build and system packages (waited for)"

# The page in Chromium, then the CLI's exports read by the Khronos glTF validator and trimesh.
e2e_rc=0
(cd tests/e2e && node --test --test-concurrency=1 page.test.mjs export.test.mjs) || e2e_rc=$?
step "e2e (beside the native tests)"
native_rc=0
wait "$native_pid" || native_rc=$?
cat "$native_log"
step "native tests and fuzz (waited for)"
# Their own times (the last line of their job when it passed) join the others.
if [ "$native_rc" = 0 ]; then report+="$(tail -1 "$native_log"), "; fi
echo "timings: ${report}total $(( $(date +%s) - t0 )) s"
if [ "$e2e_rc" != 0 ]; then echo "the e2e tests failed" >&2; fi
if [ "$native_rc" != 0 ]; then echo "the native tests or the fuzzing failed" >&2; fi
if [ "$e2e_rc" != 0 ] || [ "$native_rc" != 0 ]; then exit 1; fi
