"""Crop grid for the denoising issue: does fine structure survive the denoiser, and what do the
feature buffers change? neghip's blue lobes and the embryo's folds, at 640x360.

Columns: the reference (256 spp), NEE at 4 spp, NEE + OIDN (colour alone, albedo, albedo and
normal), the Gaussian cache after 40 warm-up frames at 4 frames, and the cache + OIDN. Rows: the
two volumes. Writes docs/results/denoise_crops.png (tone-mapped as each scene says) and prints
each crop's relMSE against the reference.

Run from the repository root with the package installed and Open Image Denoise available:
    python tools/denoise_crops.py
"""

import pathlib
import tempfile

import numpy as np

import gscache
from scene_at import scene_at

ROOT = pathlib.Path(__file__).resolve().parents[1]
W, H = 640, 360
# (scene, crop x0, y0, width, height): neghip's blue lobes; the embryo's folds.
CROPS = [
    ("default", 250, 120, 160, 120),
    ("embryo", 260, 110, 160, 120),
]


def rel_mse(a, r):
    e = np.sort(((a - r) ** 2 / (r**2 + 0.01)).mean(-1).ravel())
    return float(e[: e.size - e.size // 1000].mean())


def main():
    tmp = pathlib.Path(tempfile.mkdtemp())
    rows = []
    for name, x0, y0, cw, ch in CROPS:
        scene = scene_at(name, W, H, tmp)
        reference = gscache.render(scene, spp=256)
        image, aovs = gscache.render(scene, spp=4, seed=11, features=True)
        cache = gscache.Cache(scene)
        cached = cache.render(4, warmup=40)
        columns = [
            ("reference 256 spp", reference),
            ("NEE 4 spp", image),
            ("+ OIDN", gscache.denoise(image)),
            ("+ OIDN (albedo)", gscache.denoise(image, albedo=aovs["albedo"])),
            (
                "+ OIDN (albedo, normal)",
                gscache.denoise(image, albedo=aovs["albedo"], normal=aovs["normal"]),
            ),
            ("cache 4 frames", cached),
            ("cache + OIDN", gscache.denoise(cached)),
        ]
        crop = lambda a: a[y0 : y0 + ch, x0 : x0 + cw]
        for label, img in columns[1:]:
            print(f"{name}: {label}: crop relMSE {rel_mse(crop(img), crop(reference)):.4f}, "
                  f"image {rel_mse(img, reference):.4f}")
        rows.append(np.concatenate([crop(img) for _, img in columns], axis=1))
    grid = np.ascontiguousarray(np.concatenate(rows, axis=0), dtype=np.float32)
    out = ROOT / "docs" / "results" / "denoise_crops.png"
    gscache.write_png(str(out), grid, 0.0, "aces")
    print(f"wrote {out}: columns {', '.join(l for l, _ in columns)}")


if __name__ == "__main__":
    main()
