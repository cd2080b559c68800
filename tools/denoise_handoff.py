#!/usr/bin/env python3
"""When does the raw still image overtake the denoised one on screen? (issue 65)

For each scene, renders the still view at 1, 2, 4, ... samples a pixel with `gscache render
--denoise` (colour alone, as the viewer filters) at OIDN's `fast` and `high` qualities, and
scores the raw and the denoised PNG (tone-mapped as the viewer shows them) against a long
reference of another seed by LDR FLIP (NVIDIA's `flip-evaluator` from PyPI) and by the mean
squared error of the 8-bit image. The viewer's `--denoise-until` (the samples a pixel from
which a still view shows the raw image) is chosen from this table.

    python tools/denoise_handoff.py --scenes data/scenes/default.toml data/scenes/hydrogen.toml \\
        --size 480x270 --reference-spp 1024

Prints a Markdown table.
"""

import argparse
import os
import subprocess
import tempfile

import flip_evaluator
import numpy as np
from PIL import Image


def load(path):
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0


def render(program, scene, size, spp, out, seed, denoise=None):
    args = [program, "-q", "render", scene, "--width", str(size[0]), "--height", str(size[1]),
            "--spp", str(spp), "--seed", str(seed), "-o", out]
    if denoise:
        args += ["--denoise", "--denoise-quality", denoise]
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--program", default="target/release/gscache")
    ap.add_argument("--scenes", nargs="+", default=["data/scenes/default.toml"])
    ap.add_argument("--size", default="480x270")
    ap.add_argument("--spp", nargs="+", type=int, default=[1, 2, 4, 8, 16, 32])
    ap.add_argument("--reference-spp", type=int, default=1024)
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    work = tempfile.mkdtemp(prefix="denoise_handoff_")
    print("| scene | spp | raw FLIP | fast FLIP | high FLIP | raw MSE | fast MSE | high MSE |")
    print("|---|---|---|---|---|---|---|---|")
    for scene in args.scenes:
        name = os.path.splitext(os.path.basename(scene))[0]
        ref_path = os.path.join(work, f"{name}-ref.exr")
        render(args.program, scene, size, args.reference_spp, ref_path, seed=9001)
        ref = load(ref_path[:-4] + ".png")
        for spp in args.spp:
            cells = {}
            for quality in ["fast", "high"]:
                out = os.path.join(work, f"{name}-{spp}-{quality}.exr")
                render(args.program, scene, size, spp, out, seed=1, denoise=quality)
                raw = load(out[:-4] + ".png")
                den = load(out[:-4] + ".denoised.png")
                cells["raw"] = raw
                cells[quality] = den
            flip = {k: flip_evaluator.evaluate(ref, v, "LDR")[1] for k, v in cells.items()}
            mse = {k: float(((v - ref) ** 2).mean()) for k, v in cells.items()}
            print(f"| {name} | {spp} | {flip['raw']:.4f} | {flip['fast']:.4f} | "
                  f"{flip['high']:.4f} | {mse['raw']:.2e} | {mse['fast']:.2e} | "
                  f"{mse['high']:.2e} |", flush=True)


if __name__ == "__main__":
    main()
