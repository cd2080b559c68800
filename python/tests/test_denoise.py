"""Feature buffers from `render(..., features=True)` and `gscache.denoise`: the buffers match
the program's EXR layers' conventions, the denoiser cuts the error of a 1-spp render, and a
missing library says how to install it.

The denoising tests need Open Image Denoise (`pip install pyoidn`): where it is missing they are
skipped, unless GSCACHE_REQUIRE_OIDN=1 (CI sets it), where they fail."""

import importlib.util
import os

import numpy as np
import pytest

import gscache
from conftest import small_default_scene


def _have_oidn() -> bool:
    return "GSCACHE_OIDN" in os.environ or importlib.util.find_spec("pyoidn") is not None


needs_oidn = pytest.mark.skipif(
    not _have_oidn() and os.environ.get("GSCACHE_REQUIRE_OIDN") != "1",
    reason="Open Image Denoise is not installed (pip install pyoidn)",
)


def rel_mse(image, reference):
    """The program's relMSE: per pixel over channels, the largest 0.1% of pixels dropped."""
    per_pixel = np.sort(((image - reference) ** 2 / (reference**2 + 0.01)).mean(-1).ravel())
    return float(per_pixel[: per_pixel.size - per_pixel.size // 1000].mean())


def test_features_come_back_as_arrays_over_the_same_samples(repo, tmp_path):
    scene = gscache.Scene.load(str(small_default_scene(repo, tmp_path, 40, 30)))
    image, features = gscache.render(scene, spp=4, features=True)
    # The colour is the one a render without features gives, bit for bit.
    assert np.array_equal(image, gscache.render(scene, spp=4))
    assert features["albedo"].shape == (30, 40, 3) and features["normal"].shape == (30, 40, 3)
    assert features["depth"].shape == (30, 40) and features["coverage"].shape == (30, 40)
    cov = features["coverage"]
    assert ((cov >= 0) & (cov <= 1)).all() and (cov == 0).any() and (cov == 1).any()
    # Where no sample hit: the albedo is what the rays saw (the environment or a light, clamped
    # to [0, 1]), the normal 0, depth infinite; where all did, a finite depth.
    empty = cov == 0
    # (Away from the light's disc, whose edge pixels mix the light's clamped radiance with the
    # environment's, the albedo of a pixel that hit nothing is its colour.)
    background = empty & (image.max(-1) < 1)
    assert background.sum() > 100
    assert np.abs(features["albedo"][background] - image[background]).max() < 1e-6
    assert (features["normal"][empty] == 0).all()
    assert np.isinf(features["depth"][empty]).all()
    assert np.isfinite(features["depth"][cov == 1]).all()
    assert (np.abs(features["normal"]) <= 1).all()


@needs_oidn
def test_denoising_a_one_spp_render_cuts_its_error(repo, tmp_path):
    scene = gscache.Scene.load(str(small_default_scene(repo, tmp_path, 160, 90)))
    reference = gscache.render(scene, spp=256)
    image, features = gscache.render(scene, spp=1, seed=7, features=True)
    before = rel_mse(image, reference)
    alone = rel_mse(gscache.denoise(image), reference)
    guided = rel_mse(gscache.denoise(image, albedo=features["albedo"]), reference)
    # Measured (OIDN 2.5.1, high, seed 7): 0.105 raw, 0.0059 alone, 0.0059 with the albedo
    # (18x). Required: 8x, which no denoiser that did not run can reach.
    assert alone * 8 < before and guided * 8 < before, (before, alone, guided)
    # The defaults are the program's (denoise::Options::default()): high quality, guides
    # denoised first. Prefiltering changes the pixels, so the comparison can tell them apart.
    albedo = features["albedo"]
    by_default = gscache.denoise(image, albedo=albedo)
    assert np.array_equal(by_default, gscache.denoise(image, albedo=albedo, quality="high", prefilter=True))
    assert not np.array_equal(by_default, gscache.denoise(image, albedo=albedo, prefilter=False))
    # The normal is taken beside the albedo only.
    with pytest.raises(gscache.GscacheError, match="without an albedo"):
        gscache.denoise(image, normal=features["normal"])


@needs_oidn
def test_bad_denoiser_input_is_named():
    image = np.ones((20, 30, 3), np.float32)
    with pytest.raises(gscache.GscacheError, match="albedo"):
        gscache.denoise(image, albedo=np.ones((20, 31, 3), np.float32))
    with pytest.raises(gscache.GscacheError, match="quality"):
        gscache.denoise(image, quality="best")
    bad = image.copy()
    bad[3, 4, 0] = np.nan
    with pytest.raises(gscache.GscacheError, match=r"pixel \(4, 3\)"):
        gscache.denoise(bad)


def test_a_missing_library_says_how_to_install_it():
    image = np.ones((8, 8, 3), np.float32)
    with pytest.raises(gscache.GscacheError, match="pip install pyoidn"):
        gscache.denoise(image, library="/nonexistent/libOpenImageDenoise.so.2")


def test_a_pyoidn_in_the_current_folder_is_never_the_library(tmp_path, monkeypatch):
    """Issue 48's first item: a dataset or cloned repository that ships a ``pyoidn`` package
    (with its distribution metadata, so that a metadata search on ``sys.path`` finds it too)
    must not become the library that is loaded: loading runs its code. The current folder is
    put first on ``sys.path``, as ``python -c`` and an interactive session have it; the old
    ``find_spec`` search returned this folder's copy."""
    lib = tmp_path / "pyoidn" / "oidn" / "lib"
    lib.mkdir(parents=True)
    (tmp_path / "pyoidn" / "__init__.py").write_text("raise SystemExit('pyoidn from the folder ran')\n")
    (lib / "libOpenImageDenoise.so.2").write_bytes(b"not a library")
    info = tmp_path / "pyoidn-2.5.1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: pyoidn\nVersion: 2.5.1.0\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    found = gscache._pyoidn_library()
    assert found is None or not os.path.realpath(found).startswith(str(tmp_path.resolve())), found


@needs_oidn
def test_a_denoised_cached_movie_reads_the_cache_only_where_it_has_earned_trust(repo, tmp_path):
    # As `gscache movie --cache --denoise`: the cache takes error-aware termination's settings
    # (gs_cache's CacheConfig::for_denoiser) unless the cache dict names one of them.
    scene = gscache.Scene.load(str(small_default_scene(repo, tmp_path, 32, 18)))
    trust = {"min_coverage": 0.5, "max_bias": 0.03, "handoff_frames": 2}

    def raw(name, cache, denoise):
        folder = gscache.movie(scene, tmp_path / name, 3, spp=2, warmup=2, video=None,
                               cache={"points": 500, **cache}, denoise=denoise)
        return gscache.movie_frames(folder, 3)

    denoised = raw("denoised", {}, True)
    # `denoise=True` denoises (it once made an empty, falsy options dict and denoised nothing).
    assert (tmp_path / "denoised" / "frame_000002.denoised.exr").is_file()
    by_hand = raw("by_hand", trust, None)
    named = raw("named", {"max_bias": 0}, True)
    plain = raw("plain", {}, None)
    assert np.array_equal(denoised, by_hand)
    assert np.array_equal(named, plain)
    assert not np.array_equal(by_hand, plain)
