#!/usr/bin/env bash
# A turntable movie of every bundled scene, and a contact strip of each for the docs
# (docs/results/movies.jpg): six of every movie's twelve frames in a row, one row a scene.
#
#   bash tools/movie_strips.sh [OUT]    # default OUT = out/movie_strips
#
# Each movie is one command (printed as it runs), bit for bit the same frames on any machine
# and thread count: NEE, 32 samples a frame, a whole turn in 12 frames at 160x120. The scenes
# whose volumes live in ../shared (chest_ct, embryo) are skipped when it is missing. Needs the
# program (`cargo build --release`) and ffmpeg.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-out/movie_strips}
mkdir -p "$out"
rows=()
for scene in data/scenes/*.toml; do
    name=$(basename "$scene" .toml)
    volume=$(sed -n 's/^file = "\([^"]*\)".*/\1/p' "$scene" | head -1)
    if [ ! -e "data/scenes/$volume" ]; then
        echo "skipping $name: its volume ($volume) is not here"
        continue
    fi
    folder="$out/$name"
    cmd=(target/release/gscache -q movie "$scene" -o "$folder" --frames 12 --fps 12 --spp 32
         --width 160 --height 120 --turntable-degrees 360)
    if [ ! -e "$folder/movie.json" ]; then
        echo "${cmd[*]}"
        "${cmd[@]}"
    fi
    ffmpeg -v error -y -start_number 0 -i "$folder/frame_%06d.png" \
        -vf "select=not(mod(n\,2)),tile=6x1" -frames:v 1 "$out/$name.strip.png"
    rows+=(-i "$out/$name.strip.png")
done
n=$(( ${#rows[@]} / 2 ))
ffmpeg -v error -y "${rows[@]}" -filter_complex "vstack=inputs=$n" -q:v 4 "$out/movies.jpg"
echo "wrote $out/movies.jpg ($n scenes)"
