#!/usr/bin/env python3
"""Renders a scene with another renderer's volume path tracer and with our `render`, and compares
them: Mitsuba 3's `volpath` (`--renderer mitsuba`, from PyPI) or pbrt-v4's (`--renderer pbrt
--pbrt PATH`, built from its source; its `rgbgrid` medium, see `pbrt_medium`).

An independent check of the path tracer: Mitsuba gets the volume classified here, in numpy, from
the scene's transfer function (extinction = density_scale * opacity, albedo = colour), with
`nearest` filtering on both sides (Mitsuba interpolates pre-classified grids; we classify after
interpolating, so only nearest filtering is the same medium). Both run with unlimited path
length, so no depth convention is involved.

    pip install numpy OpenEXR mitsuba
    cargo build --release
    python3 tools/compare_renderers.py agree data/scenes/default.toml --spp 1024 --size 128
    python3 tools/compare_renderers.py variance data/scenes/one_light.toml --spp 256 --seeds 4
    python3 tools/compare_renderers.py variance data/scenes/one_light.toml --renderer pbrt --pbrt ~/pbrt-v4/build/pbrt

`agree` reports each renderer's time, the mean ratio, and the relative MSE between the two images next to
the relative MSE between two of our own renders with different seeds (the noise floor): agreement
means the first is close to the second. Block means (8x8 pixels) are also z-tested, with the
noise estimated from the seed-to-seed spread of our two renders. `variance` measures each
renderer's error per sample (relMSE x spp) over several seeds against one high-spp reference,
and the efficiency ratio 1 / (relMSE x time).
"""
import argparse
import pathlib
import re
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib

import numpy as np

DTYPES = {"uint8": "<u1", "int8": "<i1", "uint16": "<u2", "int16": "<i2", "uint32": "<u4",
          "int32": "<i4", "float32": "<f4", "float64": "<f8"}


def load_raw(scene_path, vol):
    path = (scene_path.parent / vol["file"]).resolve()
    m = re.match(r".*_(\d+)x(\d+)x(\d+)_(\w+)\.raw$", path.name)
    dims = vol.get("dims") or [int(m.group(i)) for i in (1, 2, 3)]
    dtype = vol.get("dtype") or m.group(4)
    order = "<" if vol.get("byte_order", "little") == "little" else ">"
    a = np.fromfile(path, dtype=DTYPES[dtype].replace("<", order), offset=vol.get("header_bytes", 0))
    return path, dims, a.reshape(dims[2], dims[1], dims[0]).astype(np.float64)


def classify(values, tf):
    lo, hi = tf.get("window") or (values.min(), values.max())
    t = np.clip((values - lo) / (hi - lo), 0.0, 1.0)
    pts = tf["points"]
    xs = [p["value"] for p in pts]
    sigma = tf["density_scale"] * np.interp(t, xs, [p["opacity"] for p in pts])
    albedo = np.stack([np.interp(t, xs, [p["color"][c] for p in pts]) for c in range(3)], axis=-1)
    return sigma.astype(np.float32), albedo.astype(np.float32)


def classified_box(scene_path, desc):
    """The scene's volume classified here (extinction and albedo grids, z slowest) and its
    world-space box: (dims, sigma, albedo, lowest corner, size)."""
    vol = desc["volume"]
    _, dims, values = load_raw(scene_path, vol)
    sigma, albedo = classify(values, desc["transfer"])
    spacing = np.array(vol.get("spacing", [1, 1, 1]), dtype=float)
    size_w = np.array(dims, dtype=float) * spacing
    origin = np.array(vol["origin"]) if "origin" in vol else -0.5 * size_w
    return dims, sigma, albedo, origin, size_w


def mitsuba_render(scene_path, desc, spp, size, seed, variant):
    import mitsuba as mi
    mi.set_variant(variant)
    from mitsuba import ScalarTransform4f as T

    _, sigma, albedo, origin, size_w = classified_box(scene_path, desc)
    # gridvolume maps [0,1]^3 to the box; cube shape spans [-1,1]^3.
    grid_to_world = T().translate(origin.tolist()).scale(size_w.tolist())
    cube_to_world = T().translate((origin + 0.5 * size_w).tolist()).scale((0.5 * size_w).tolist())
    phase = desc.get("phase", {"kind": "isotropic"})
    phase_dict = {"type": "hg", "g": phase["g"]} if phase["kind"] in ("hg", "henyeygreenstein") else {"type": "isotropic"}
    medium = {
        "type": "heterogeneous",
        "sigma_t": {"type": "gridvolume", "grid": mi.VolumeGrid(sigma[..., None]),
                    "filter_type": "nearest", "to_world": grid_to_world},
        "albedo": {"type": "gridvolume", "grid": mi.VolumeGrid(albedo),
                   "filter_type": "nearest", "to_world": grid_to_world},
        "scale": 1.0,
        "phase": phase_dict,
    }
    cam = desc["camera"]
    scene = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 5},
        "sensor": {
            "type": "perspective", "fov_axis": "y", "fov": cam["fov_y"],
            "to_world": T().look_at(origin=cam["eye"], target=cam["target"], up=cam.get("up", [0, 1, 0])),
            "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                     "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
        },
        "volume": {"type": "cube", "to_world": cube_to_world, "bsdf": {"type": "null"}, "interior": medium},
    }
    env = desc.get("environment", {}).get("radiance", [0, 0, 0])
    if max(env) > 0:
        scene["env"] = {"type": "constant", "radiance": {"type": "rgb", "value": env}}
    for i, l in enumerate(desc.get("light", [])):
        scene[f"light{i}"] = {"type": "sphere", "center": l["center"], "radius": l["radius"],
                              "emitter": {"type": "area", "radiance": {"type": "rgb", "value": l["radiance"]}}}
    s = mi.load_dict(scene)
    t0 = time.time()
    img = np.array(mi.render(s, spp=spp, seed=seed))
    return img[..., :3].astype(np.float64), time.time() - t0


def pbrt_medium(scene_path, desc, tmp):
    """Writes the classified volume as a pbrt-v4 `rgbgrid` medium inside a box; returns the file.

    `rgbgrid` is pbrt-v4's one grid medium whose albedo varies per voxel (the `uniformgrid`
    medium scales one sigma_a and sigma_s by a density). It interpolates the classified grids
    trilinearly, so it is not quite our `nearest` medium: compare per-sample variance by the seed
    spread, which needs no common expectation, and the means only as a check of the set-up.
    """
    dims, sigma, albedo, lo, size_w = classified_box(scene_path, desc)
    hi = lo + size_w
    s = sigma[..., None].astype(np.float64)
    sigma_s = (s * albedo).reshape(-1, 3)
    sigma_a = (s * (1.0 - albedo)).reshape(-1, 3)
    phase = desc.get("phase", {"kind": "isotropic"})
    g = phase["g"] if phase["kind"] in ("hg", "henyeygreenstein") else 0.0
    fmt = lambda a: " ".join(f"{x:.7g}" for x in a.ravel())
    corners = [[(lo, hi)[(i >> k) & 1][k] for k in range(3)] for i in range(8)]
    # Twelve triangles of the box, wound outwards (pbrt's "interface" material ignores winding).
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = [i for a, b, c, d in quads for i in (a, b, c, a, c, d)]
    path = tmp / "medium.pbrt"
    path.write_text(
        f'MakeNamedMedium "volume" "string type" "rgbgrid" "float g" {g}\n'
        f'  "integer nx" {dims[0]} "integer ny" {dims[1]} "integer nz" {dims[2]}\n'
        f'  "point3 p0" [{fmt(lo)}] "point3 p1" [{fmt(hi)}]\n'
        f'  "rgb sigma_a" [{fmt(sigma_a)}]\n  "rgb sigma_s" [{fmt(sigma_s)}]\n'
        "AttributeBegin\n  MediumInterface \"volume\" \"\"\n  Material \"interface\"\n"
        f'  Shape "trianglemesh" "point3 P" [{fmt(np.array(corners))}] "integer indices" [{" ".join(map(str, tris))}]\n'
        "AttributeEnd\n")
    return path


def read_exr(path):
    try:
        import OpenEXR
    except ImportError:
        sys.exit("reading our EXR output needs the OpenEXR package: pip install OpenEXR")
    with OpenEXR.File(str(path), separate_channels=True) as f:
        ch = f.channels()
        return np.stack([ch[c].pixels for c in "RGB"], axis=-1).astype(np.float64)


def read_pfm(path):
    with open(path, "rb") as f:
        kind = f.readline().strip()
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    channels = 3 if kind == b"PF" else 1
    return data.reshape(h, w, channels)[::-1].astype(np.float64)  # PFM rows run bottom to top


def pbrt_render(binary, desc, medium, spp, size, seed, tmp, threads):
    """pbrt-v4's `volpath` with the independent sampler and a box pixel filter; returns the image
    and the wall time of the whole process (`pbrt_setup_time` measures what to subtract)."""
    cam = desc["camera"]
    up = cam.get("up", [0, 1, 0])
    out = tmp / f"pbrt_{spp}_{seed}.pfm"
    lines = [
        # pbrt's camera space is left-handed: mirror x so the image is not flipped against ours.
        "Scale -1 1 1",
        f"LookAt {' '.join(map(str, cam['eye']))}  {' '.join(map(str, cam['target']))}  {' '.join(map(str, up))}",
        f'Camera "perspective" "float fov" {cam["fov_y"]}',
        f'Sampler "independent" "integer pixelsamples" {spp} "integer seed" {seed}',
        'Integrator "volpath" "integer maxdepth" 100000',
        'PixelFilter "box" "float xradius" 0.5 "float yradius" 0.5',
        f'Film "rgb" "integer xresolution" {size} "integer yresolution" {size} "string filename" "{out}"',
        "WorldBegin",
    ]
    env = desc.get("environment", {}).get("radiance", [0, 0, 0])
    if max(env) > 0:
        lines.append(f'LightSource "infinite" "rgb L" [{" ".join(map(str, env))}]')
    for light in desc.get("light", []):
        lines += ["AttributeBegin", f"  Translate {' '.join(map(str, light['center']))}",
                  f'  AreaLightSource "diffuse" "rgb L" [{" ".join(map(str, light["radiance"]))}]',
                  f'  Shape "sphere" "float radius" {light["radius"]}', "AttributeEnd"]
    lines.append(f'Include "{medium}"')
    scene = tmp / f"pbrt_{spp}_{seed}.pbrt"
    scene.write_text("\n".join(lines) + "\n")
    t0 = time.time()
    r = subprocess.run([binary, "--quiet", "--nthreads", str(threads), str(scene)], capture_output=True, text=True)
    elapsed = time.time() - t0
    if r.returncode != 0:
        sys.exit(f"pbrt failed on {scene}:\n{r.stderr}{r.stdout}")
    return read_pfm(out), elapsed


def other_renderer(args, scene_path, desc, tmp):
    """The renderer we compare with, as (label, render(spp, seed) -> (image, seconds)).

    Mitsuba's seconds exclude scene loading and a first, kernel-compiling render. pbrt's exclude
    parsing and building the scene: the median of three 1-spp runs of the whole process is
    subtracted from each run (which leaves pbrt one sample per pixel of render time in hand).
    """
    if args.renderer == "mitsuba":
        mitsuba_render(scene_path, desc, 1, args.size, 0, args.variant)
        return (f"mitsuba {args.variant}",
                lambda spp, seed: mitsuba_render(scene_path, desc, spp, args.size, seed, args.variant))
    medium = pbrt_medium(scene_path, desc, tmp)
    setup = float(np.median([pbrt_render(args.pbrt, desc, medium, 1, args.size, 7 + i, tmp, args.threads)[1]
                             for i in range(3)]))
    print(f"pbrt: scene parsing and set-up {setup:.2f} s (median of three 1-spp runs), subtracted")

    def render(spp, seed):
        img, t = pbrt_render(args.pbrt, desc, medium, spp, args.size, seed, tmp, args.threads)
        return img, t - setup
    return "pbrt-v4 volpath", render


def gray_scene(desc):
    """The scene with every colour replaced by its luminance: a diagnostic that takes away the
    colour noise of a spectral renderer (pbrt-v4 traces four wavelengths per sample, and a medium
    whose albedo varies by channel spreads them)."""
    lum = lambda c: [float(np.dot([0.2126, 0.7152, 0.0722], c))] * 3
    d = {k: (dict(v) if isinstance(v, dict) else v) for k, v in desc.items()}
    d["transfer"]["points"] = [dict(p, color=lum(p["color"])) for p in desc["transfer"]["points"]]
    if "light" in desc:
        d["light"] = [dict(l, radiance=lum(l["radiance"])) for l in desc["light"]]
    if "environment" in desc:
        d["environment"]["radiance"] = lum(desc["environment"]["radiance"])
    return d


def our_render(binary, scene_path, desc, spp, size, seed, tmp):
    d = dict(desc)
    vol = dict(desc["volume"])
    vol["file"] = str((scene_path.parent / vol["file"]).resolve())
    vol["filter"] = "nearest"
    d["volume"] = vol
    path = tmp / f"scene_{seed}.toml"
    path.write_text(to_toml(d))
    out = tmp / f"ours_{seed}.exr"
    t0 = time.time()
    r = subprocess.run([binary, "render", str(path), "--spp", str(spp), "--width", str(size), "--height", str(size),
                        "--max-depth", "-1", "--seed", str(seed), "-o", str(out), "-q"],
                       capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(r.stderr)
    img = read_exr(out)
    return img, time.time() - t0, r.stdout.strip()


def to_toml(d):
    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {val(x)}" for k, x in v.items()) + " }"
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(v)
    lines = []
    for k, v in d.items():
        if isinstance(v, list) and v and isinstance(v[0], dict):
            for item in v:
                lines.append(f"[[{k}]]")
                lines += [f"{a} = {val(b)}" for a, b in item.items()]
        else:
            lines.append(f"[{k}]")
            lines += [f"{a} = {val(b)}" for a, b in v.items()]
    return "\n".join(lines) + "\n"


def relmse(a, b, eps=0.01):
    return float(np.mean((a - b) ** 2 / (b ** 2 + eps)))


def agree(args):
    """Pixel-by-pixel agreement: two of our renders and one of Mitsuba's at the same spp."""
    scene_path = pathlib.Path(args.scene).resolve()
    desc = tomllib.loads(scene_path.read_text())
    with tempfile.TemporaryDirectory() as t:
        tmp = pathlib.Path(t)
        ours_a, t_a, line = our_render(args.binary, scene_path, desc, args.spp, args.size, 1, tmp)
        ours_b, t_b, _ = our_render(args.binary, scene_path, desc, args.spp, args.size, 2, tmp)
        label, render = other_renderer(args, scene_path, desc, tmp)
        mits, t_m = render(args.spp, 3)
    flipped = mits[:, ::-1]
    ours = 0.5 * (ours_a + ours_b)
    # Noise floor: two of our renders with different seeds, each at spp.
    floor = relmse(ours_a, ours_b)
    r_direct, r_flip = relmse(ours_a, mits), relmse(ours_a, flipped)
    lum = np.array([0.2126, 0.7152, 0.0722])
    print(f"scene {scene_path.name}, {args.size}x{args.size}, {args.spp} spp, unlimited path length, nearest filter")
    print(f"ours:    {t_a:.2f} s ({line})")
    print(f"{label}: {t_m:.2f} s")
    print(f"time ratio theirs/ours: {t_m / t_a:.2f}")
    print(f"relMSE(ours seed 1, theirs) = {r_direct:.3e}  (mirrored: {r_flip:.3e})")
    print(f"relMSE(ours seed 1, ours seed 2) = {floor:.3e}  (noise floor)")
    print(f"mean luminance: ours {np.mean(ours @ lum):.5f}, theirs {np.mean(mits @ lum):.5f}, "
          f"ratio {np.mean(ours @ lum) / np.mean(mits @ lum):.5f}")
    # Block z-test on 8x8-pixel means of luminance. The variance of one of our pixels is
    # estimated from the seed pair, (a - b)^2 / 2, averaged over the block's 64 pixels; Mitsuba's
    # is assumed equal to ours (same estimator family, same spp). A relative floor of 1e-5 covers
    # f32 rounding where both images are noiseless (pixels that see only the environment).
    k = 8
    h = args.size // k
    la, lb, lm = ours_a @ lum, ours_b @ lum, mits @ lum
    blk = lambda im: im[: h * k, : h * k].reshape(h, k, h, k).mean(axis=(1, 3))
    var_pixel = blk((la - lb) ** 2 / 2)
    var_block = var_pixel / (k * k)
    ours_mean = blk(0.5 * (la + lb))
    m_mean = blk(lm)
    z = (ours_mean - m_mean) / np.sqrt(var_block / 2 + var_block + (1e-5 * m_mean) ** 2 + 1e-30)
    print(f"8x8 blocks: mean z {z.mean():+.3f}, rms z {np.sqrt((z ** 2).mean()):.3f} (1 if they agree), "
          f"fraction |z| > 3: {(np.abs(z) > 3).mean():.4f} (0.0027 if they agree; {z.size} blocks)")


def variance(args):
    """Per-sample variance and efficiency: `seeds` renders each at `spp` against one reference.

    relMSE x spp is the error of one sample, comparable across spp; it is measured two ways:
    against a high-spp reference of ours (minus the reference's own share, estimated from the
    seed spread), and from the seed spread alone (the per-pixel sample variance across seeds over
    reference^2 + eps, which needs the reference only to normalise). Efficiency is
    1 / (relMSE x time) with each renderer's median render time (Mitsuba's excludes scene loading
    and its first, JIT-compiling render).
    """
    scene_path = pathlib.Path(args.scene).resolve()
    desc = tomllib.loads(scene_path.read_text())
    if args.gray:
        desc = gray_scene(desc)
    cache = pathlib.Path(args.reference_dir)
    cache.mkdir(parents=True, exist_ok=True)
    ref_path = cache / f"{scene_path.stem}{'_gray' if args.gray else ''}_{args.size}_{args.reference_spp}.npy"
    with tempfile.TemporaryDirectory() as t:
        tmp = pathlib.Path(t)
        if ref_path.exists():
            ref = np.load(ref_path)
        else:
            ref, t_ref, _ = our_render(args.binary, scene_path, desc, args.reference_spp, args.size, 9999, tmp)
            np.save(ref_path, ref)
            print(f"reference: {args.reference_spp} spp in {t_ref:.1f} s -> {ref_path}")
        ours = [our_render(args.binary, scene_path, desc, args.spp, args.size, 1 + s, tmp)[:2]
                for s in range(args.seeds)]
        label, render = other_renderer(args, scene_path, desc, tmp)
        theirs = [render(args.spp, 101 + s) for s in range(args.seeds)]
    eps = 0.01
    print(f"scene {scene_path.name}, {args.size}x{args.size}, {args.spp} spp x {args.seeds} seeds, "
          f"reference {args.reference_spp} spp (ours), unlimited path length, nearest filter, "
          f"against {label}")
    rows = {}
    for name, runs in (("ours", ours), ("theirs", theirs)):
        imgs = np.stack([r[0] for r in runs])
        times = np.array([r[1] for r in runs])
        per_seed = np.array([relmse(im, ref, eps) for im in imgs]) * args.spp
        spread = imgs.var(axis=0, ddof=1) / (ref ** 2 + eps)
        spread_spp = float(spread.mean()) * args.spp
        # The reference's own noise adds spread/reference_spp to each render's relMSE.
        ref_share = spread_spp / args.reference_spp
        mean = per_seed.mean() - ref_share
        half = 1.96 * per_seed.std(ddof=1) / np.sqrt(len(per_seed))
        t_med = float(np.median(times))
        rows[name] = (mean, spread_spp, t_med)
        print(f"{name:8s} relMSE x spp {mean:.4f} +- {half:.4f} (95%, seeds {', '.join(f'{x:.4f}' for x in per_seed)}; "
              f"reference share {ref_share:.1e} removed), seed spread {spread_spp:.4f}, "
              f"median time {t_med:.2f} s, efficiency {1 / (mean / args.spp * t_med):.1f}")
    (eo, so, to), (em, sm, tm) = rows["ours"], rows["theirs"]
    print(f"ours / theirs: relMSE x spp {eo / em:.3f} (seed spread {so / sm:.3f}), time {to / tm:.3f}, "
          f"efficiency ratio {(em * tm) / (eo * to):.2f}x (by seed spread {(sm * tm) / (so * to):.2f}x)")


def main():
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="mode", required=True)
    for mode, spp in (("agree", 1024), ("variance", 256)):
        p = sub.add_parser(mode)
        p.add_argument("scene")
        p.add_argument("--spp", type=int, default=spp)
        p.add_argument("--size", type=int, default=128)
        p.add_argument("--binary", default="target/release/gscache")
        p.add_argument("--renderer", choices=("mitsuba", "pbrt"), default="mitsuba")
        p.add_argument("--variant", default="scalar_rgb",
                       help="Mitsuba variant: scalar_rgb, or llvm_ad_rgb (vectorised JIT; needs libLLVM)")
        p.add_argument("--pbrt", default="pbrt", help="pbrt-v4's executable, built from source")
        p.add_argument("--threads", type=int, default=2, help="pbrt's --nthreads")
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--reference-spp", type=int, default=16384)
    p.add_argument("--reference-dir", default="out/compare_renderers")
    p.add_argument("--gray", action="store_true", help="every colour replaced by its luminance (see gray_scene)")
    args = ap.parse_args()
    if args.renderer == "pbrt" and shutil.which(args.pbrt) is None:
        sys.exit(f"pbrt executable {args.pbrt!r} not found: build pbrt-v4 from source and pass its path "
                 "with --pbrt")
    (agree if args.mode == "agree" else variance)(args)

if __name__ == "__main__":
    main()
