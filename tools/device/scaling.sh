#!/usr/bin/env bash
# Issue 31's scaling figures on a many-core machine, in one call.
#
#   bash tools/device/scaling.sh BINARY OUTDIR
#
# THREADS (default "16 8 4") lists the thread counts of the cache runs; PLAIN=0 skips the plain
# tracing series and SPLAT=0 the rasteriser's bench, for a shorter call.
#
# BINARY is a release `gscache` built elsewhere (the device machine has no Rust); every run's
# output goes to OUTDIR/log, and the lines that carry the figures are printed last. Each cache
# run prints its per-frame parts, which sum to the frame's wall time; the 1-against-21-frame
# pair checks that sum from outside (wall time of the whole process).
set -u
bin=$1
out=$2
log=$out/log
scene=data/scenes/default.toml
img=$(mktemp -d)
n=$(nproc)
echo "machine: $(lscpu | sed -n 's/^Model name: *//p'), $n CPUs" | tee "$log"

run() { # label, then the render's arguments
    local label=$1
    shift
    local t0 t1
    t0=$(date +%s.%N)
    "$bin" render "$scene" -q "$@" -o "$img/x.exr" >"$img/run.txt" 2>&1
    local rc=$?
    t1=$(date +%s.%N)
    {
        echo "== $label (rc $rc, process wall $(awk "BEGIN{printf \"%.3f\", $t1 - $t0}") s): $*"
        cat "$img/run.txt"
    } | tee -a "$log" | grep -E "^==|per frame|per warm-up|samples/s" | sed "s|$img/||"
}

hd=(--width 1280 --height 720 --spp 1)
# Plain tracing, 1 to all threads, about 2 s each.
if [ "${PLAIN:-1}" != 0 ]; then
    for ts in "1 2" "2 4" "4 8" "8 16" "16 32" "16 32"; do
        set -- $ts
        run "plain $1" --width 1280 --height 720 --spp "$2" --threads "$1"
    done
fi
# Both caches, both runs of the issue's table.
for t in ${THREADS:-16 8 4}; do
    for c in --cache --nrc; do
        run "$c defaults $t" "$c" --warmup 40 --frames 20 "${hd[@]}" --threads "$t"
        run "$c cold $t" "$c" --warmup 0 --frames 60 --cache-handoff-frames 0 "${hd[@]}" --threads "$t"
    done
done
# The frame's wall time from outside: 1 and 21 frames after 40 warm-up frames.
run "--cache wall 1 frame" --cache --warmup 40 --frames 1 "${hd[@]}" --threads 16
run "--cache wall 21 frames" --cache --warmup 40 --frames 21 "${hd[@]}" --threads 16
# The ray-traced lookup against the rasterised one.
for size in "1280 720" "320 180"; do
    set -- $size
    run "raster lookup $1x$2" --cache --warmup 40 --frames 20 --width "$1" --height "$2" --spp 1 --threads 16
    run "rt lookup $1x$2" --cache --cache-lookup rt --warmup 40 --frames 20 --width "$1" --height "$2" --spp 1 --threads 16
done
# The rasteriser.
[ "${SPLAT:-1}" != 0 ] && "$bin" bench splat --max-gaussians 300000 --no-scalar --reps 5 --threads 16 -q 2>&1 | tee -a "$log" | grep -E "300k|Lanes8.*plant|AdamW"
rm -rf "$img"
