#!/usr/bin/env bash
# Installs what the page and the tests need on a fresh Debian machine; quick when all is there.
#   bash tests/setup.sh serve   # Rust wasm target, wasm-bindgen-cli (the page's build, tools/page.sh)
#   bash tests/setup.sh test    # the above + Chromium, Mesa's Vulkan (lavapipe), npm packages
#   bash tests/setup.sh system  # only Chromium, Mesa's Vulkan, the npm packages and trimesh (Python)
#   bash tests/setup.sh tools   # only the wasm target and wasm-bindgen-cli
set -euo pipefail
cd "$(dirname "$0")/.."
what="${1:-test}"
WASM_BINDGEN_VERSION=0.2.130   # must equal the wasm-bindgen version pinned in Cargo.toml

export PATH="${CARGO_HOME:-$HOME/.cargo}/bin:$HOME/.cargo/bin:$PATH"

tools() {
  # cargo install builds in a temporary directory of its own, not in the tests' target dir
  # (sharing it would make the parallel builds wait for each other's lock).
  unset CARGO_TARGET_DIR
  # tests/all.sh lints this crate by running clippy as its compiler; not a tool's own code.
  unset RUSTC_WORKSPACE_WRAPPER CLIPPY_ARGS
  rustup target list --installed | grep -q wasm32-unknown-unknown || rustup target add wasm32-unknown-unknown
  # wasm-bindgen-cli ships no prebuilt binary through a registry this machine reaches
  # (crates.io has sources only, npm and PyPI have none), so it is compiled once, for compile
  # speed: it rewrites a 30 MB module (lightly optimised). No LTO, no debug info. (The page's
  # own build, tools/page.sh, does what trunk did with it, so no trunk is compiled.)
  export CARGO_PROFILE_RELEASE_LTO=false CARGO_PROFILE_RELEASE_DEBUG=false \
    CARGO_PROFILE_RELEASE_CODEGEN_UNITS=64 CARGO_PROFILE_RELEASE_STRIP=true
  if ! wasm-bindgen --version 2>/dev/null | grep -q "$WASM_BINDGEN_VERSION"; then
    CARGO_PROFILE_RELEASE_OPT_LEVEL=1 cargo install wasm-bindgen-cli --version "$WASM_BINDGEN_VERSION"
  fi
}

system() {
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
  if ! command -v chromium >/dev/null || ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1; then
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium mesa-vulkan-drivers >/dev/null
  fi
  (cd tests/e2e && npm ci --no-audit --no-fund --loglevel=error)
  # trimesh, a Python mesh reader, for the export test: its own environment, outside the repo.
  local py="$HOME/.cache/terrain-py"
  if ! "$py/bin/python" -c "import trimesh" 2>/dev/null; then
    python3 -m venv "$py"
    "$py/bin/pip" install -q --disable-pip-version-check trimesh==4.8.3 numpy==2.4.6
  fi
}

case "$what" in
  serve|tools) tools ;;
  system) system ;;
  test) system; tools ;;
  *) echo "usage: bash tests/setup.sh [serve|test|system|tools]" >&2; exit 2 ;;
esac
