#!/usr/bin/env bash
# Prepares a GPU training run here, before any GPU machine is started: the release trainer
# (x86-64, stripped, gzip-compressed) and the DEMs it trains on go to .gpu/ (ignored by git;
# name it in the device tool's `carry`), the Vulkan loader's Debian packages to .gl/.
#
#   bash tools/gpu/pack.sh            # every trainer's data (the default DEM set below)
#   DEMS="id1 id2" bash tools/gpu/pack.sh
#
# The DEM set: the Tyrol 5 m/1 m DEMs and the 2 m tile (sketch windows at the format's
# scale), the finest mountain DEMs (sketch windows up to kilometres, the TCM's 128 m
# windows and the ×4 step's 32 m ones, the TEM's levels). About 27 MB of the 64 MiB a device
# call may carry.
set -euo pipefail
cd "$(dirname "$0")/../.."
export PATH="$HOME/.cargo/bin:$PATH"
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/terrain-target}"
shared="${SHARED:-../shared}"
DEMS="${DEMS:-avaframe_alr_5m avaframe_gar_5m avaframe_hit_5m avaframe_kot_5m avaframe_mal_5m avaframe_wog_5m avaframe_pfa_1m pdalintro_devilstower_2m glaciers_aiguestortes_20m glaciers_mtperdu_20m glaciers_sthelens_10m orometry_pyrenees_30m topotoolbox_bigtujunga_30m}"

grep -qx '/.gpu/' .git/info/exclude 2>/dev/null || echo '/.gpu/' >> .git/info/exclude
grep -qx '/.gl/' .git/info/exclude 2>/dev/null || echo '/.gl/' >> .git/info/exclude

cargo build --release --bin terrain
rm -rf .gpu && mkdir -p .gpu/data
gzip -9 -c "$CARGO_TARGET_DIR/release/terrain" > .gpu/terrain.gz
cp -r "$shared/sketch_pairs" .gpu/sketch_pairs
python3 - "$shared/dem" .gpu/data $DEMS <<'PY'
import json, shutil, sys
src, dst, ids = sys.argv[1], sys.argv[2], sys.argv[3:]
m = json.load(open(f"{src}/manifest.json"))
known = {d["id"]: d for d in m["dems"]}
missing = [i for i in ids if i not in known]
if missing:
    sys.exit(f"not in {src}/manifest.json: {missing}")
m["dems"] = [known[i] for i in ids]
for d in m["dems"]:
    shutil.copy(f"{src}/{d['file']}", f"{dst}/{d['file']}")
json.dump(m, open(f"{dst}/manifest.json", "w"), indent=1)
PY

# The Vulkan loader and glvnd for the GPU machine: its NVIDIA driver brings the Vulkan ICD
# (libGLX_nvidia), which needs glvnd's libGLdispatch, but neither the loader nor glvnd.
if [ ! -d .gl ] || ! ls .gl/libvulkan1_*.deb .gl/libglvnd0_*.deb > /dev/null 2>&1; then
  mkdir -p .gl /tmp/amd64/partial
  o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
  apt-get $o update > /dev/null
  (cd .gl && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 > /dev/null)
fi
du -sh .gpu .gl
echo "packed: $(ls .gpu/data/*.tif | wc -l) DEMs, trainer $(stat -c %s .gpu/terrain.gz) bytes gzip"
