#!/usr/bin/env bash
# One training on whatever GPU this machine has, from what tools/gpu/pack.sh left in .gpu/
# (carry .gpu and .gl to the device machine). Writes checkpoints every minute and the log to
# $OUT (default train-runs/gpu), so a run cut off still brings its last minute back.
#
#   bash tools/gpu/train.sh MODEL MINUTES [extra arguments of the trainer]
#     MODEL: sketch | vae | tcm | tem | bench (each trainer for MINUTES, examples/s only)
#       | infer (inference timings, MINUTES ignored: tile-bench and tem-bench on the GPU and
#       on the CPU kernels, JSON lines in the log)
#   RESUME=DIR: go on from the checkpoint in DIR (a folder that came back from an earlier run,
#     or a CPU run's checkpoint folder); BACKEND=cpu runs the same on the CPU; PACK=1 leaves
#     the checkpoint folder as tar parts of ≤ 15 MiB (what the device tool brings back);
#     STAGE_TIMEOUT=S stops a stage that runs past S seconds; STEPS, FINETUNE: see tem below.
#
# A dry run here (Mesa's lavapipe, seconds): OUT=/tmp/gpu-dry bash tools/gpu/train.sh bench 0.1
set -uo pipefail
cd "$(dirname "$0")/../.."
model="${1:?MODEL: sketch | vae | tcm | tem | bench}"
minutes="${2:?MINUTES}"
shift 2
out="${OUT:-train-runs/gpu}"
mkdir -p "$out"
backend="${BACKEND:-gpu}"
log="$out/train.log"

# On a GPU machine: the carried Vulkan loader, and the NVIDIA driver's Vulkan ICD.
if command -v nvidia-smi > /dev/null; then
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee -a "$log"
  # The driver's Vulkan ICD (libGLX_nvidia) needs glvnd's libGLdispatch besides the loader.
  if ! ldconfig -p | grep -q libvulkan.so.1 || ! ldconfig -p | grep -q libGLdispatch.so.0; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
  fi
  icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  [ -f "$icd" ] && export VK_DRIVER_FILES="$icd"
fi
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/xdg-$(id -u)}"
mkdir -p -m 700 "$XDG_RUNTIME_DIR"

# Unpacked outside the tree, so .gpu stays what pack.sh made (the carry limit is 64 MiB).
bin="${TMPDIR:-/tmp}/terrain-gpu-trainer"
gzip -dc .gpu/terrain.gz > "$bin" && chmod +x "$bin" || exit 1
data=.gpu/data
common=(--backend "$backend" --minutes "$minutes" --checkpoint-minutes 1)

# The checkpoint folder of MODEL, resumed from $RESUME where given.
ckpt() {
  local dir="$out/$1"
  if [ -n "${RESUME:-}" ]; then
    mkdir -p "$dir" && cp -r "$RESUME"/. "$dir"/
    echo "$dir --resume"
  else
    echo "$dir"
  fi
}

run() {
  local what="$1"
  shift
  echo "== $what: $*" | tee -a "$log"
  local t0
  t0=$(date +%s%N)
  # STAGE_TIMEOUT (seconds, 0 = none) bounds a stage that hangs, so the next one still runs.
  timeout "${STAGE_TIMEOUT:-0}" "$bin" "$@" 2>&1 | tee -a "$log"
  local rc=${PIPESTATUS[0]}
  echo "== $what: exit $rc after $(( ($(date +%s%N) - t0) / 1000000 )) ms" | tee -a "$log"
  return "$rc"
}

# A checkpoint folder as tar parts of at most 15 MiB each ($OUT/NAME.tar.part-aa, -ab, …: the
# device tool brings back files of up to 16 MB): `cat NAME.tar.part-* | tar x` here.
pack_back() {
  local name="$1"
  [ -d "$out/$name" ] || return 0
  tar -cf - -C "$out" "$name" | split -b 15m - "$out/$name.tar.part-" && rm -rf "${out:?}/$name"
  ls -l "$out"/"$name".tar.part-* | tee -a "$log"
}
# Only when asked (PACK=1, on the device machine): a local run keeps its folder as it is.
trap '[ "${PACK:-0}" = 1 ] && pack_back "$model"' EXIT

case "$model" in
  sketch)
    run sketch train-sketch --dem-dir "$data" --checkpoint $(ckpt sketch) --steps 1000000 --checkpoint-every 1000000 "${common[@]}" "$@" ;;
  vae)
    run vae train-sketch --model vae --dem-dir "$data" --checkpoint $(ckpt vae) --steps 1000000 --checkpoint-every 1000000 "${common[@]}" "$@" ;;
  tcm)
    run tcm train-tcm --dem-dir "$data" --checkpoint $(ckpt tcm) --steps 1000000 --checkpoint-every 1000000 "${common[@]}" "$@" ;;
  tem)
    init=()
    [ -n "${RESUME:-}" ] && init=(--init "$RESUME")
    # STEPS / FINETUNE: the chained and single-level step counts (the learning rate drops to a
    # third for the last quarter of the chained steps and the fine-tuning).
    run tem train-tem --dem-dir "$data" --out "$out/tem" --steps "${STEPS:-1000000}" --finetune "${FINETUNE:-0}" --checkpoint-every 0 "${init[@]}" "${common[@]}" "$@" ;;
  infer)
    # The world's networks per phase batch and the TEM's levels per batch, on this machine's
    # GPU (burn wgpu) and its CPU kernels, one JSON line each.
    rc=0
    run tile-bench-gpu tile-bench --gpu --repeats 10 || rc=1
    run tile-bench-cpu tile-bench --repeats 10 || rc=1
    for level in 0 1 2 3 4; do
      for b in 1 16; do
        run "tem-bench-gpu-$level-$b" tem-bench --gpu --level "$level" --batch "$b" --repeats 10 || rc=1
      done
    done
    exit "$rc" ;;
  bench)
    # Each trainer for MINUTES on small pools: the examples/s of its summary line (this
    # bench's lines only: the log gathers every run into the same $OUT).
    rc=0
    before=$(wc -l < "$log")
    run bench-tem train-tem --dem-dir "$data" --out "$out/bench/tem" --steps 100000 --checkpoint-every 0 --batch 12 --backend "$backend" --minutes "$minutes" || rc=1
    run bench-tcm train-tcm --dem-dir "$data" --checkpoint "$out/bench/tcm" --steps 100000 --checkpoint-every 100000 --batch 8 --backend "$backend" --minutes "$minutes" || rc=1
    run bench-sketch train-sketch --dem-dir "$data" --checkpoint "$out/bench/sketch" --steps 100000 --checkpoint-every 100000 --batch 8 --crop 256 --pool 32 --validation 4 --loss band-l1 --backend "$backend" --minutes "$minutes" || rc=1
    run bench-vae train-sketch --model vae --dem-dir "$data" --checkpoint "$out/bench/vae" --steps 100000 --checkpoint-every 100000 --batch 8 --crop 256 --pool 32 --validation 4 --backend "$backend" --minutes "$minutes" || rc=1
    rm -rf "$out/bench"
    tail -n +"$((before + 1))" "$log" | grep -h '"examples_per_s"' | sed 's/^/result: /'
    exit $rc ;;
  *)
    echo "unknown model $model (sketch | vae | tcm | tem | bench | infer)" >&2
    exit 2 ;;
esac
