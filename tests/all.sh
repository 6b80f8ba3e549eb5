#!/usr/bin/env bash
# Every test: native unit and integration tests (world, schedule, LOD, links, CLI, burn on
# Vulkan/lavapipe), the release build of the page with trunk, and the headless-Chromium
# end-to-end test of that page on WebGPU. Prints the page's size and the e2e report.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tests/setup.sh test
export PATH="$HOME/.cargo/bin:$PATH"
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/terrain-target}"
# burn's wgpu runtime natively: Vulkan through Mesa's software rasteriser.
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/xdg-$(id -u)}"; mkdir -p -m 700 "$XDG_RUNTIME_DIR"

start=$(date +%s)
cargo test --all-targets
native_done=$(date +%s)

trunk build --release
wasm=$(ls dist/*.wasm); js=$(ls dist/*.js)
raw=$(( $(stat -c %s "$wasm") + $(stat -c %s "$js") ))
gz=$(( $(gzip -9 -c "$wasm" | wc -c) + $(gzip -9 -c "$js" | wc -c) ))
echo "page size: wasm+js $raw bytes raw, $gz bytes gzip"
web_done=$(date +%s)

(cd tests/e2e && node --test --test-concurrency=1 page.test.mjs)
end=$(date +%s)
echo "timings: native tests $((native_done - start)) s, page build $((web_done - native_done)) s, e2e $((end - web_done)) s"
