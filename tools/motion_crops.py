#!/usr/bin/env python3
"""Crops of frames in motion, at equal time, for issue 53's write-up (docs/results/cache_error.md).

For each scene it makes five short movies with `gscache movie` (a 24-degree turntable, 8 frames
of 100 ms each after a 30-frame warm-up for the cache): NEE + OIDN (fast, albedo); the cache raw
before and after its targets were weighted per colour channel and pooled over frames (issue 53:
`--cache-stopper-weights`, `--cache-channel-weights`, `--cache-weighted-loss`, all on by default
now); and the cache + OIDN as the program denoises it (reading a level only where it has earned
trust: `CacheConfig::for_denoiser`), before and after the same change. It takes the last frame
of each beside that frame's NEE reference (512 spp); the crops go side by side into one small
JPEG.

Run from the repository root, with the program built (`cargo build --release`), ffmpeg not
needed (`--video none`), Pillow installed and GSCACHE_OIDN set:

    python tools/motion_crops.py --out out/motion_crops --jpeg docs/results/motion_crops.jpg
"""

import argparse
import subprocess
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

PROGRAM = Path("target/release/gscache")
# (scene, crop box in the 320x180 frame: left, top, right, bottom)
SCENES = [
    ("hydrogen", (100, 30, 220, 150)),
    ("default", (100, 20, 240, 160)),
    ("embryo", (90, 20, 230, 160)),
]
DENOISE = ["--denoise", "--denoise-quality", "fast", "--denoise-guides", "albedo",
           "--denoise-raw-guides"]
# The cache's settings before issue 53's per-channel weights (stopper weights by luminance
# for the denoised cache, none for the raw one): the "before" columns.
BEFORE = ["--cache-channel-weights", "false", "--cache-weighted-loss", "false"]
METHODS = [
    ("NEE + OIDN", [] + DENOISE, ".denoised.png"),
    ("cache, before", ["--cache", "--warmup", "30", "--cache-stopper-weights", "false"] + BEFORE,
     ".png"),
    ("cache", ["--cache", "--warmup", "30"], ".png"),
    ("trusted cache + OIDN, before", ["--cache", "--warmup", "30"] + BEFORE + DENOISE,
     ".denoised.png"),
    ("trusted cache + OIDN", ["--cache", "--warmup", "30"] + DENOISE, ".denoised.png"),
]
FRAMES = 8


def movie(scene, name, flags, out, reference):
    folder = out / scene / name.replace(" ", "").replace("+", "_")
    if (folder / "movie.json").exists():
        return folder
    cmd = [str(PROGRAM), "movie", f"data/scenes/{scene}.toml", "-o", str(folder),
           "--width", "320", "--height", "180", "--frames", str(FRAMES), "--fps", "10",
           "--turntable-degrees", "24", "--frame-seconds", "0.1", "--video", "none", "-q"]
    cmd += flags
    if reference:
        cmd += ["--reference-spp", "512"]
    subprocess.run(cmd, check=True)
    return folder


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, default=Path("out/motion_crops"))
    ap.add_argument("--jpeg", type=Path, default=Path("out/motion_crops/motion_crops.jpg"))
    ap.add_argument("--scale", type=int, default=2)
    args = ap.parse_args()
    last = f"frame_{FRAMES - 1:06d}"
    rows = []
    for scene, box in SCENES:
        tiles = []
        ref_folder = None
        for i, (name, flags, suffix) in enumerate(METHODS):
            folder = movie(scene, name, flags, args.out, reference=(i == 0))
            if i == 0:
                ref_folder = folder
            tiles.append((name, Image.open(folder / f"{last}{suffix}").convert("RGB")))
        # The NEE + OIDN movie's reference of that frame, tone-mapped as the frames are.
        ref_exr = ref_folder / "reference" / f"{last}.exr"
        ref_png = args.out / scene / "reference.png"
        if not ref_png.exists():
            tonemap_exr(ref_exr, ref_png, scene)
        tiles.append(("reference (512 spp)", Image.open(ref_png).convert("RGB")))
        rows.append((scene, [(n, t.crop(box)) for n, t in tiles]))
    w = max(sum(t.width for _, t in r) for _, r in rows) * args.scale
    h = sum(max(t.height for _, t in r) for _, r in rows) * args.scale
    label_h = 14
    sheet = Image.new("RGB", (w, h + label_h * (len(rows) + 1)), (20, 20, 20))
    draw = ImageDraw.Draw(sheet)
    y = label_h
    for c, (name, _) in enumerate(rows[0][1]):
        draw.text((c * rows[0][1][0][1].width * args.scale + 4, 1), name, fill=(230, 230, 230))
    for scene, tiles in rows:
        x = 0
        draw.text((4, y), scene, fill=(230, 230, 230))
        y += label_h
        for _, t in tiles:
            big = t.resize((t.width * args.scale, t.height * args.scale), Image.NEAREST)
            sheet.paste(big, (x, y))
            x += big.width
        y += max(t.height for _, t in tiles) * args.scale
    args.jpeg.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(args.jpeg, quality=85)
    print(f"wrote {args.jpeg}")


def tonemap_exr(exr, png, scene):
    """The reference EXR tone-mapped as the program maps a frame (the scene's exposure and tone
    map, through the package's own writer)."""
    import tomllib

    import gscache

    out = tomllib.loads(Path(f"data/scenes/{scene}.toml").read_text()).get("output", {})
    image = np.asarray(gscache.read_exr(str(exr)), dtype=np.float32)
    gscache.write_png(str(png), image, float(out.get("exposure", 0.0)), out.get("tonemap", "aces"))


if __name__ == "__main__":
    main()
