"""Where the cache's error comes from, raw and after the denoiser (issue 53's breakdown).

For one scene at a still camera, K frames of 1 spp are rendered by plain NEE and by the
Gaussian cache (after its warm-up, training between frames as in the viewer), each frame also
denoised by Intel Open Image Denoise (high, colour alone). Against a converged NEE reference,
every pixel's error over the frames splits into

    E[(x - r)^2] = (E[x] - r)^2 + Var[x]
                   bias^2          noise (frame to frame)

with the bias estimated without the frames' own noise ((mean - r)^2 - Var / K) and the relMSE
weight 1 / (r^2 + 0.01) of the project's metric (untrimmed here, so the parts add up). The
parts are reported for the whole image and per region, the regions taken from the reference's
coverage (the fraction of its camera rays that scattered at all): `empty` (0), `thin` (up to
0.5: silhouettes and halos, where few paths reach and train the cache) and `dense`. The signed
luminance bias per region says whether the cache is too dark or too bright there.

Variants (`--variant`, any key of the cache table, several joined by commas) isolate a cause:
`levels=1` caches only the first scattering vertex, `early=false` leaves only natural
termination, `frozen` stops training after the warm-up (its frame-to-frame noise is then the
paths' alone, the rest of a trained cache's is its training's), `warmup=400` a longer-trained
cache.

Writes `OUT/breakdown.md` (the tables) and small JPEG maps of the signed relative bias
(blue: too dark, red: too bright) for the raw and denoised cache and the denoised NEE.

Run from the repository root with the package installed, Open Image Denoise available and
Pillow (for the maps):
    python tools/cache_error.py --scene hydrogen --frames 64 --out out/cache_error
"""

import argparse
import json
import pathlib
import tempfile
import time

import numpy as np

import gscache
from scene_at import scene_at

EPSILON = 0.01


class Moments:
    """Per-pixel sums over frames, in f64."""

    def __init__(self, regions: dict):
        self.n = 0
        self.sum = None
        self.sum2 = None
        self.regions = regions
        self.region_sums = {name: [] for name in regions}

    def add(self, image: np.ndarray):
        x = image.astype(np.float64)
        if self.sum is None:
            self.sum = np.zeros_like(x)
            self.sum2 = np.zeros_like(x)
        self.sum += x
        self.sum2 += x * x
        self.n += 1
        for name, mask in self.regions.items():
            self.region_sums[name].append(x[mask].sum(0))

    def mean(self) -> np.ndarray:
        return self.sum / self.n

    def variance(self) -> np.ndarray:
        m = self.mean()
        return np.maximum(self.sum2 / self.n - m * m, 0.0) * self.n / max(self.n - 1, 1)


def luminance(x: np.ndarray) -> np.ndarray:
    return 0.2126 * x[..., 0] + 0.7152 * x[..., 1] + 0.0722 * x[..., 2]


def parts(m: Moments, reference: np.ndarray, region: str) -> dict:
    """relMSE per frame split into bias^2 and noise over the pixels of `region`."""
    mask = m.regions[region]
    weight = 1.0 / (reference.astype(np.float64) ** 2 + EPSILON)
    var = m.variance()
    bias2 = np.maximum((m.mean() - reference) ** 2 - var / m.n, 0.0)
    sel = mask[..., None].repeat(3, -1)
    b = float((weight * bias2)[sel].mean()) if sel.any() else 0.0
    v = float((weight * var)[sel].mean()) if sel.any() else 0.0
    ref_lum = luminance(reference)[mask].sum()
    signed = float((luminance(m.mean())[mask].sum() - ref_lum) / max(ref_lum, 1e-12))
    # Per colour channel: the region's mean against the reference's, and the standard error of
    # that figure from the frames' own spread (pixels of one frame summed first, so their
    # correlation is kept): a bias is measured where it is several of these.
    mean = m.mean()[mask].sum(0)
    ref = reference.astype(np.float64)[mask].sum(0)
    channel = (mean - ref) / np.maximum(ref, 1e-12)
    frame_sums = np.array(m.region_sums[region])
    stderr = frame_sums.std(0, ddof=1) / np.sqrt(len(frame_sums)) / np.maximum(ref, 1e-12)
    return {"bias2": b, "noise": v, "total": b + v, "signed_bias": signed,
            "channel_bias": channel.tolist(), "channel_stderr": stderr.tolist()}


def bias_map(m: Moments, reference: np.ndarray, path: pathlib.Path, scale: float):
    """Signed relative luminance bias as a JPEG: blue too dark, red too bright, white 0."""
    from PIL import Image

    r = luminance(reference)
    d = (luminance(m.mean()) - r) / (r + 0.05)
    t = np.clip(d / scale, -1, 1)
    rgb = np.ones(t.shape + (3,))
    rgb[..., 0] -= np.clip(-t, 0, 1)
    rgb[..., 1] -= np.abs(t)
    rgb[..., 2] -= np.clip(t, 0, 1)
    Image.fromarray((rgb * 255).astype(np.uint8)).save(path, quality=85)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="hydrogen")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=180)
    ap.add_argument("--frames", type=int, default=64)
    ap.add_argument("--warmup", type=int, default=40)
    ap.add_argument("--reference-spp", type=int, default=4096)
    ap.add_argument("--variant", action="append", default=[],
                    help="cache variants: KEY=VALUE of the cache table (several joined by "
                         "commas), frozen, warmup=N (repeatable)")
    ap.add_argument("--out", default="out/cache_error")
    args = ap.parse_args()
    out = pathlib.Path(args.out) / args.scene
    out.mkdir(parents=True, exist_ok=True)
    tmp = pathlib.Path(tempfile.mkdtemp())
    scene = scene_at(args.scene, args.width, args.height, tmp)

    ref_file = out / f"reference_{args.reference_spp}.npy"
    if ref_file.exists():
        reference = np.load(ref_file)
    else:
        t = time.time()
        reference = gscache.render(scene, spp=args.reference_spp, seed=1000)
        np.save(ref_file, reference)
        print(f"reference {args.reference_spp} spp in {time.time() - t:.1f} s")
    _, features = gscache.render(scene, spp=64, seed=2000, features=True)
    coverage = features["coverage"]
    regions = {
        "all": np.ones(coverage.shape, bool),
        "empty": coverage == 0,
        "thin": (coverage > 0) & (coverage <= 0.5),
        "dense": coverage > 0.5,
    }

    def measure(label, frame):
        raw, den = Moments(regions), Moments(regions)
        t = time.time()
        for k in range(args.frames):
            image = frame(k)
            raw.add(image)
            den.add(gscache.denoise(image))
        seconds = time.time() - t
        rows = []
        for stage, m in (("raw", raw), ("OIDN", den)):
            for region, mask in regions.items():
                rows.append({"method": label, "stage": stage, "region": region,
                             "pixels": int(mask.sum()), **parts(m, reference, region)})
        print(f"{label}: {args.frames} frames in {seconds:.1f} s; " + ", ".join(
            f"{r['stage']} {r['region']} {r['total']:.5f} ({r['signed_bias']:+.2%})"
            for r in rows if r["region"] != "empty"), flush=True)
        return raw, den, rows

    results = []
    nee_raw, nee_den, rows = measure("nee", lambda k: gscache.render(scene, spp=1, seed=k + 1))
    results += rows
    variants = ["default"] + args.variant
    maps = {"nee_oidn": nee_den}
    for v in variants:
        config, warmup, frozen = {}, args.warmup, False
        for part in v.split(","):
            key, _, value = part.partition("=")
            if key == "warmup":
                warmup = int(value)
            elif key == "frozen":
                frozen = True
            elif value:
                config[key] = json.loads(value)
            elif key != "default":
                raise SystemExit(f"unknown variant {v}")
        cache = gscache.Cache(scene, config or None)
        cache.render(1, warmup=warmup)
        if frozen:
            cache = gscache.Cache.load(scene, _saved(cache, tmp, v), {**config, "train": False})
        label = f"cache ({v})"
        raw, den, rows = measure(label, lambda k: cache.render(1))
        results += rows
        maps[f"cache_{v}_raw"] = raw
        maps[f"cache_{v}_oidn"] = den

    for name, m in maps.items():
        bias_map(m, reference, out / f"bias_{name.replace('=', '')}.jpg", 0.2)
    (out / "breakdown.json").write_text(json.dumps(results, indent=1))
    lines = [
        f"# {args.scene}: the error per frame, raw and after OIDN, split into bias² and noise",
        "",
        f"{args.width}x{args.height}, still camera, {args.frames} frames of 1 spp, cache warm-up "
        f"{args.warmup} frames (still), reference {args.reference_spp} spp. relMSE weight "
        f"1/(r²+{EPSILON}), untrimmed; bias² has the frames' own noise removed; signed bias is "
        "the region's luminance against the reference's.",
        "",
        "| method | stage | region | pixels | relMSE | bias² | noise | bias² share | signed bias "
        "| R / G / B bias (standard error) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        share = r["bias2"] / r["total"] if r["total"] > 0 else 0.0
        lines.append(
            f"| {r['method']} | {r['stage']} | {r['region']} | {r['pixels']} | "
            f"{r['total']:.5f} | {r['bias2']:.5f} | {r['noise']:.5f} | {share:.0%} | "
            f"{r['signed_bias']:+.2%} | "
            + " / ".join(f"{b:+.2%}" for b in r["channel_bias"])
            + f" ({max(r['channel_stderr']):.2%}) |"
        )
    (out / "breakdown.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def _saved(cache, folder: pathlib.Path, name: str) -> str:
    path = folder / f"cache-{name}"
    cache.save(str(path))
    return str(path)


if __name__ == "__main__":
    main()
