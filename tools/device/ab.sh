#!/usr/bin/env bash
# Two builds of `gscache` alternated on one machine (old, new, old, new), the cached frame's runs
# of issue 31's table at one thread count: per-frame parts and process wall times of each, so
# a change is judged on the same machine in the same call (lent machines differ by 10-20%).
#
#   bash tools/device/ab.sh OLD_BINARY NEW_BINARY OUTDIR
#
# THREADS (default 16) sets the thread count; REPS (default 2) the rounds.
set -u
old=$1
new=$2
out=$3
log=$out/ab.log
img=$(mktemp -d)
t=${THREADS:-16}
hd=(--width 1280 --height 720 --spp 1 --threads "$t")
for rep in $(seq "${REPS:-2}"); do
    for which in old new; do
        bin=$old
        [ "$which" = new ] && bin=$new
        for c in --cache --nrc; do
            for run in defaults cold; do
                if [ "$run" = defaults ]; then
                    a=(--warmup 40 --frames 20)
                else
                    a=(--warmup 0 --frames 60 --cache-handoff-frames 0)
                fi
                t0=$(date +%s.%N)
                "$bin" render data/scenes/default.toml -q "$c" "${a[@]}" "${hd[@]}" -o "$img/x.exr" >"$img/run.txt" 2>&1
                t1=$(date +%s.%N)
                {
                    echo "== $which $c $run, round $rep (process wall $(awk "BEGIN{printf \"%.3f\", $t1 - $t0}") s)"
                    grep -E "^per frame" "$img/run.txt"
                } | tee -a "$log"
            done
        done
    done
done
rm -rf "$img"
