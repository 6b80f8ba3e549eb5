#!/usr/bin/env bash
# Two trainings of one model side by side on the one GPU of this machine (tools/gpu/train.sh
# each, from what tools/gpu/pack.sh left in .gpu/), each with its own extra arguments: two
# recipes tried in the time of one. On an H200 two TCM runs made 55.7 + 55.4 examples/s
# together, where one run alone made 90.8 on an H100 (weights/manifest.json, gpu_runs).
# Each run's log and checkpoint folder go to $OUT/a and $OUT/b; with PACK=1 only the
# snapshots and the run's state come back, as tar parts of at most 15 MiB
# (`cat snaps.tar.part-* | tar x` here): the device tool brings back at most 8 files.
#
#   bash tools/gpu/side_by_side.sh MODEL MINUTES "ARGS OF A" "ARGS OF B"
#
# A dry run here on the CPU (seconds):
#   OUT=/tmp/sbs BACKEND=cpu bash tools/gpu/side_by_side.sh tcm 0.2 "--init weights --tcm-only --snapshots" "--init weights --tcm-only --snapshots --drainage 10"
set -u
cd "$(dirname "$0")/../.."
model="${1:?MODEL: sketch | vae | tcm}"
minutes="${2:?MINUTES}"
args_a="${3:?ARGS OF A}"
args_b="${4:?ARGS OF B}"
out="${OUT:-train-runs/gpu}"
mkdir -p "$out/a" "$out/b"
# The driver's Vulkan loader once, before both runs look for it.
if command -v nvidia-smi > /dev/null; then
  nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
  if ! ldconfig -p | grep -q libvulkan.so.1 || ! ldconfig -p | grep -q libGLdispatch.so.0; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
  fi
fi
# Each run unpacks the trainer into its own TMPDIR. PACK is handled here, not by train.sh.
run() {
  local name="$1" args="$2"
  mkdir -p "/tmp/sbs-$name"
  # shellcheck disable=SC2086 # the extra arguments are words
  TMPDIR="/tmp/sbs-$name" OUT="$out/$name" PACK=0 bash tools/gpu/train.sh "$model" "$minutes" $args > /dev/null 2>&1
}
run a "$args_a" &
sleep 15 # the first run's trainer is unpacked and started before the second one's
run b "$args_b" &
while [ -n "$(jobs -r)" ]; do
  sleep 30
  tail -n 1 "$out"/a/train.log "$out"/b/train.log 2> /dev/null | cut -c1-200
done
wait
if [ "${PACK:-0}" = 1 ]; then
  for name in a b; do
    dir="$out/$name/$model"
    [ -d "$dir" ] || continue
    # The snapshots (with --snapshots) and the run's state; the optimisers stay behind.
    (cd "$out/$name" && tar -cf snaps.tar $(ls -d "$model"/snapshots "$model"/*_state.json 2> /dev/null) && rm -rf "$model" &&
      split -b 15m snaps.tar snaps.tar.part- && rm snaps.tar)
  done
  ls -lR "$out"
fi
grep -h '"examples_per_s"\|: exit' "$out"/a/train.log "$out"/b/train.log | cut -c1-300
