#!/usr/bin/env bash
# Builds the page into dist/, or builds it and serves it on loopback:
#   bash tools/page.sh build          # the release page in dist/
#   bash tools/page.sh serve [PORT]   # build, then http://127.0.0.1:PORT/ (default 8080)
# Installs what it needs first (the wasm target and wasm-bindgen-cli, tests/setup.sh tools).
#
# The page is the library built for wasm32 with the page's cargo profile (Cargo.toml:
# [profile.page]) and without the native features, bound by wasm-bindgen for the web, with
# www/index.html, www/style.css and weights/ beside it. The glue, module and style sheet carry
# a hash of their content in their names (a new build is never mixed with a cached old one),
# and every address in the page is relative, so dist/ can be served from any host and path
# (the root, or /terrain/ of a project site). TERRAIN_PAGE_URL, the address the page will be
# published at (https://host/path, no trailing slash), makes the link preview's picture an
# absolute address, as Open Graph readers want; without it the address is relative.
set -euo pipefail
cd "$(dirname "$0")/.."
what="${1:-build}"
export PATH="${CARGO_HOME:-$HOME/.cargo}/bin:$HOME/.cargo/bin:$PATH"

build() {
  bash tests/setup.sh tools
  cargo rustc --lib --crate-type cdylib --target wasm32-unknown-unknown --profile page --no-default-features
  local target_dir
  target_dir=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
  local wasm="$target_dir/wasm32-unknown-unknown/page/terrain.wasm"
  local hash stage css_hash
  hash=$(sha256sum "$wasm" | cut -c1-16)
  stage=$(mktemp -d "${TMPDIR:-/tmp}/terrain-dist.XXXXXX")
  wasm-bindgen --target web --no-typescript --out-dir "$stage" --out-name "terrain-$hash" "$wasm"
  css_hash=$(sha256sum www/style.css | cut -c1-16)
  cp www/style.css "$stage/style-$css_hash.css"
  cp -r weights "$stage/weights"
  cp www/preview.jpg "$stage/preview.jpg"
  local page_url="${TERRAIN_PAGE_URL:-.}"
  sed -e "s/{{glue}}/terrain-$hash.js/g" -e "s/{{wasm}}/terrain-${hash}_bg.wasm/g" -e "s/{{css}}/style-$css_hash.css/g" \
    -e "s|{{page_url}}|${page_url%/}|g" www/index.html > "$stage/index.html"
  if grep -q '{{' "$stage/index.html"; then echo "www/index.html has a placeholder this script does not fill" >&2; exit 1; fi
  chmod -R a+rX "$stage"
  rm -rf dist.old
  if [ -e dist ]; then mv dist dist.old; fi
  mv "$stage" dist
  rm -rf dist.old
  echo "page built in dist/ (terrain-$hash: $(stat -c %s "dist/terrain-${hash}_bg.wasm") bytes of wasm)"
}

case "$what" in
  build) build ;;
  serve)
    build
    port="${2:-8080}"
    echo "serving the page at http://127.0.0.1:$port/"
    exec python3 -m http.server --bind 127.0.0.1 --directory dist "$port"
    ;;
  *) echo "usage: bash tools/page.sh [build|serve [PORT]]" >&2; exit 2 ;;
esac
