#!/usr/bin/env bash
# The ablations behind the cache's start-up defaults (BENCHMARKS.md, "The cache from its first
# frames"): the warm start (warm_start_frames 0 against 32), adaptive training (off against on),
# the fallback (off against on, with a light move and a transfer-function edit), the cache's
# resolution divisor (4 against 3 and 2) and the handoff in long images (0, 8, 16, 32 frames), each on neghip, hydrogen, headsq and chest CT (chest CT
# needs ../shared/data), 320x180, 3 seeds, 40 warm-up frames along the runner's orbit.
#
# Usage: bash tools/cache_start_ablations.sh [OUT]   (default OUT: target/cache-start-ablations)
# Each experiment writes OUT/<ablation>_<volume>/report.md; references are shared with the
# committed experiments (target/experiment-references).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
out="${1:-$root/target/cache-start-ablations}"
mkdir -p "$out"
cargo build --release --manifest-path "$root/Cargo.toml"
bin="$root/target/release/gscache"

# The light move of the volume's standard experiment.
light_offset() {
  grep -m1 "light_offset" "$root/experiments/$1.toml" | sed 's/.*= *//'
}

for volume in default hydrogen headsq chest_ct; do
  if [ "$volume" = chest_ct ] && [ ! -d "$root/../shared/data" ]; then
    echo "chest_ct skipped: ../shared/data is absent"
    continue
  fi
  header() {
    cat <<EOF
name = "$1_$volume"
scene = "$root/data/scenes/$volume.toml"
width = 320
height = 180
seeds = [1, 2, 3]
output = "$out/$1_$volume"
[reference]
spp = 1024
dir = "$root/target/experiment-references"
[budgets]
spp = [1, 16, 64]
seconds = [0.05, 0.2, 1.0]
[[method]]
name = "nee"
integrator = "nee"
EOF
  }
  method() {
    printf '[[method]]\nname = "%s"\nintegrator = "nee"\ncache = { lookup = "raster", warmup = 40%s }\n' "$1" "$2"
  }
  {
    header warm_start
    method "Adam alone" ", warm_start_frames = 0"
    method "warm start 32" ", warm_start_frames = 32"
  } >"$out/warm_start_$volume.toml"
  {
    header adaptive
    method "every frame" ", adaptive_training = false"
    method "adaptive" ", adaptive_training = true"
  } >"$out/adaptive_$volume.toml"
  {
    header divisor
    method "divisor 4" ""
    method "divisor 3" ", resolution_divisor = 3"
    method "divisor 2" ", resolution_divisor = 2"
  } >"$out/divisor_$volume.toml"
  {
    header handoff
    method "no handoff" ", handoff_frames = 0"
    method "handoff 8" ", handoff_frames = 8"
    method "handoff 16" ", handoff_frames = 16"
    method "handoff 32" ", handoff_frames = 32"
  } >"$out/handoff_$volume.toml"
  {
    header fallback
    method "no fallback" ", fallback = false"
    method "fallback" ", fallback = true"
    for edit in "light moves:light_offset = $(light_offset "$volume")" \
      "transfer function edit:density_scale = 3.0"; do
      printf '[[flythrough]]\nname = "%s"\nframes = 60\nwarmup = 20\n' "${edit%%:*}"
      printf 'methods = ["nee", "no fallback", "fallback"]\nerror_every = 5\n'
      printf '[[flythrough.event]]\nframe = 40\n%s\n' "${edit#*:}"
    done
  } >"$out/fallback_$volume.toml"
  for ablation in warm_start adaptive divisor handoff fallback; do
    "$bin" experiment "$out/${ablation}_$volume.toml"
  done
done
