"""The radiance cache from Python (train, save, load), Gaussian clouds against the program, the
EXR round trip and the example."""

import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

import gscache
from conftest import run_program, small_default_scene

ASSET = "data/splats/fruit_drops_minimal.ply"
VIEW = {"eye": [0.76, -0.2, -1.4], "target": [0.76, 0.13, -2.1], "width": 64, "height": 48}


def small_scene(repo, tmp_path):
    return gscache.Scene.load(str(small_default_scene(repo, tmp_path, 64, 48)))


def test_cache_trains_saves_and_loads(repo, tmp_path):
    scene = small_scene(repo, tmp_path)
    cache = gscache.Cache(scene, {"levels": 2})
    assert cache.levels == 2 and cache.gaussian_count > 0
    image = cache.render(4, warmup=8, spp=1)
    assert image.shape == (48, 64, 3) and np.isfinite(image).all() and image.mean() > 0.0
    assert cache.frames == 12
    costs = cache.costs_ms
    assert set(costs) == {"trace", "lookup", "train"} and all(v >= 0 for v in costs.values())
    levels = cache.level_images()
    assert len(levels) == 2 and levels[0].max() > 0.0
    cache.save(str(tmp_path / "levels"))
    assert sorted(os.listdir(tmp_path / "levels")) == ["length_1.ply", "length_2.ply", "manifest.json"]
    loaded = gscache.Cache.load(scene, str(tmp_path / "levels"), {"levels": 2})
    again = loaded.level_images()
    # Not bit for bit: the files store colour x radiance scale, and loading rounds each colour
    # once (f32). The drawn levels agree to 2e-6 of their peak.
    for a, b in zip(levels, again):
        assert np.abs(a - b).max() <= 2e-6 * a.max()
    with pytest.raises(gscache.GscacheError, match="unknown field"):
        gscache.Cache(scene, {"levelz": 2})


@pytest.mark.parametrize("how", ["render", "render-stochastic", "exact", "stochastic"])
def test_clouds_equal_the_programs_images(repo, program, tmp_path, how):
    cloud = gscache.Cloud.read(str(repo / ASSET))
    assert len(cloud) > 1000
    eye, target = (",".join(map(str, VIEW[k])) for k in ("eye", "target"))
    size = ["--width", "64", "--height", "48", "--eye", eye, "--target", target]
    out = tmp_path / "p.exr"
    kw = dict(width=64, height=48)
    if how.startswith("render"):
        extra = ["--stochastic", "4"] if how == "render-stochastic" else []
        done = run_program(program, "splat", "render", ASSET, *size, *extra, "-o", out)
        image = gscache.splat_render(cloud, VIEW["eye"], VIEW["target"],
                                     stochastic=4 if extra else None, **kw)
    else:
        done = run_program(program, "splat", "trace", ASSET, *size, "--mode", how, "--spp", "4", "-o", out)
        image = gscache.splat_trace(cloud, VIEW["eye"], VIEW["target"], mode=how, spp=4, **kw)
    assert done.returncode == 0, done.stderr
    expect = gscache.read_exr(str(out))
    assert image.max() > 0.0
    assert np.array_equal(image.view(np.uint32), expect.view(np.uint32))


def test_images_round_trip_and_clouds_write(repo, tmp_path):
    image = np.random.default_rng(1).random((5, 7, 3), dtype=np.float32)
    gscache.write_exr(str(tmp_path / "a.exr"), image)
    assert np.array_equal(gscache.read_exr(str(tmp_path / "a.exr")), image)
    gscache.write_png(str(tmp_path / "a.png"), image, exposure=1.0, tonemap="aces")
    assert (tmp_path / "a.png").stat().st_size > 0
    with pytest.raises(gscache.GscacheError, match="tonemap"):
        gscache.write_png(str(tmp_path / "b.png"), image, tonemap="reinhard")
    with pytest.raises(gscache.GscacheError, match="cannot read"):
        gscache.read_exr(str(tmp_path / "missing.exr"))
    cloud = gscache.Cloud.read(str(repo / ASSET))
    cloud.write(str(tmp_path / "c.ply"))
    assert len(gscache.Cloud.read(str(tmp_path / "c.ply"))) == len(cloud)


def test_the_example_runs(repo, tmp_path):
    pytest.importorskip("nibabel")
    env = dict(os.environ, GSCACHE_EXAMPLE_OUT=str(tmp_path), GSCACHE_EXAMPLE_SIZE="64")
    done = subprocess.run(
        [sys.executable, str(repo / "examples/brain_nifti.py")],
        capture_output=True, text=True, env=env, timeout=600,
    )
    assert done.returncode == 0, done.stderr
    for name in ("brain_nee.png", "brain_cache.png", "brain_nee.exr", "brain_cache.exr"):
        assert (tmp_path / name).stat().st_size > 0, name


def test_the_docs_brain_snippet_runs(repo, tmp_path):
    """docs/python.md's numpy snippet runs as written, on nibabel's T1 crop at 96x96 and 16
    spp, and draws something: over 2% of the pixels differ from the background (the corner
    pixel) by more than 0.05 after x / (1 + x). Whether it looks like anatomy is judged by eye,
    in the contact sheet (tools/contact_sheet.py)."""
    nibabel = pytest.importorskip("nibabel")
    text = (repo / "docs/python.md").read_text()
    code = text.split("```python\nimport numpy as np, nibabel, gscache\n", 1)[1].split("```", 1)[0]
    t1 = pathlib.Path(nibabel.__file__).parent / "tests" / "data" / "anatomical.nii"
    code = (
        code.replace('"brain.nii.gz"', repr(str(t1)))
        .replace('"width": 512, "height": 512', '"width": 96, "height": 96')
        .replace("spp=64, progress=print", "spp=16")
        .replace('"brain.png"', repr(str(tmp_path / "brain.png")))
    )
    names = {}
    exec("import numpy as np, nibabel, gscache\n" + code, names)
    assert (tmp_path / "brain.png").stat().st_size > 0
    x = np.asarray(names["image"], dtype=np.float64)
    x = x / (1.0 + x)
    covered = (np.abs(x - x[0, 0]).max(axis=2) > 0.05).mean()
    assert covered > 0.02, f"the snippet draws {covered:.3f} of the image: nothing to see"


def test_the_unbiased_cache_renders_nee_on_average(repo, tmp_path):
    """The unbiased cache (gs-cache's crate docs) with q = 0.5 luminance(throughput), so that
    most paths stop into it: the image means of 96 frames of 4 spp of it and of 96 independent
    NEE images of 4 spp agree within 4.42 standard errors (a two-sided false alarm of 1e-5). tests/unbiased.rs holds
    the same per pixel, paired, on every volume; this checks the settings reach the cache from
    Python."""
    scene = small_scene(repo, tmp_path)
    cache = gscache.Cache(scene, {"unbiased": True, "continuation_scale": 0.5})
    cache.render(1, warmup=16, spp=1)
    n = 96
    cached = np.array([cache.render(1, spp=4).mean() for _ in range(n)], dtype=np.float64)
    nee = np.array(
        [gscache.render(scene, spp=4, seed=1000 + i).mean() for i in range(n)], dtype=np.float64
    )
    se = np.sqrt(cached.var(ddof=1) / n + nee.var(ddof=1) / n)
    assert se < 0.01 * nee.mean(), f"the test sees too little: se {se} of {nee.mean()}"
    assert abs(cached.mean() - nee.mean()) < 4.42 * se, (cached.mean(), nee.mean(), se)
    with pytest.raises(gscache.GscacheError, match="min_continuation"):
        gscache.Cache(scene, {"unbiased": True, "min_continuation": 0.0})
