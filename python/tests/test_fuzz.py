"""A fixed-seed fuzz of the package's entry points: arrays of every shape, dtype and stride,
scene tables with numbers replaced by extremes, render arguments at their limits, and pickled
partial films with flipped bytes. Each case must return a finite result or raise one of the
package's clear errors: never crash the interpreter, hang, or return a silently wrong value.
The seeds are fixed, so a failure is reproduced by running the test again; the counts of each
outcome are printed (pytest -s)."""

import collections
import copy
import pickle

import numpy as np
import pytest

import gscache
from conftest import small_default_scene

# What a refusal may raise: the package's own error, or Python's for a wrong type or value.
REFUSALS = (gscache.GscacheError, TypeError, ValueError, OverflowError, MemoryError)

EXTREMES = [0, -1, 1e30, -1e30, float("nan"), float("inf"), 2**32, 2**64, 1e-45, "x", None, []]


def test_arrays_of_any_shape_dtype_and_stride(capsys):
    rng = np.random.default_rng(20261125)
    seen = collections.Counter()
    dtypes = [np.uint8, np.int8, np.uint16, np.int16, np.float32, np.float64, np.int64, np.bool_]
    for case in range(300):
        dtype = dtypes[rng.integers(len(dtypes))]
        ndim = int(rng.integers(0, 5))
        shape = tuple(int(x) for x in rng.integers(0, 7, size=ndim))
        a = (rng.random(shape) * 300).astype(dtype)
        if a.dtype.kind == "f" and a.size and rng.random() < 0.3:
            a.flat[int(rng.integers(a.size))] = [np.nan, np.inf, -np.inf][int(rng.integers(3))]
        if a.ndim == 3 and rng.random() < 0.3:
            a = a[::-1, :, ::2]
        if rng.random() < 0.1:
            a = np.broadcast_to(np.zeros(1, dtype), (int(rng.integers(1, 10**6)),) * 3)
        try:
            v = gscache.Volume.from_array(a)
            seen["read"] += 1
            assert a.ndim == 3 and a.size > 0, f"case {case}: {a.shape} was read"
            del v
        except REFUSALS:
            seen["refused"] += 1
    print("arrays:", dict(seen))
    assert seen["read"] > 10 and seen["refused"] > 10


def test_scene_tables_with_extreme_numbers(repo, tmp_path):
    rng = np.random.default_rng(7)
    path = small_default_scene(repo, tmp_path, 8, 6)
    base = {
        "transfer": {"window": [0, 255], "density_scale": 1.0,
                     "points": [{"value": 0.0, "color": [1, 1, 1], "opacity": 0.0},
                                {"value": 1.0, "color": [0.8, 0.6, 0.4], "opacity": 1.0}]},
        "camera": {"eye": [60, 45, 95], "target": [0, 0, 0], "up": [0, 1, 0], "fov_y": 30,
                   "width": 8, "height": 6},
        "lights": [{"center": [60, 70, 40], "radius": 10, "radiance": [3, 3, 3]},
                   {"type": "distant", "direction": [0, -1, 0], "irradiance": [1, 1, 1]}],
        "environment": [0.1, 0.1, 0.1],
        "spacing": [1, 1, 1],
    }
    volume = gscache.Volume.from_array(
        np.fromfile(repo / "data/volumes/neghip_64x64x64_uint8.raw", np.uint8).reshape(64, 64, 64)
    )
    seen = collections.Counter()
    for case in range(150):
        tables = copy.deepcopy(base)
        # Replace one number somewhere with an extreme.
        leaves = []

        def walk(node):
            items = node.items() if isinstance(node, dict) else enumerate(node)
            for k, v in items:
                if isinstance(v, (dict, list)):
                    walk(v)
                else:
                    leaves.append((node, k))

        walk(tables)
        node, key = leaves[int(rng.integers(len(leaves)))]
        node[key] = EXTREMES[int(rng.integers(len(EXTREMES)))]
        try:
            scene = gscache.Scene(volume, **tables)
        except REFUSALS:
            seen["refused"] += 1
            continue
        try:
            img = gscache.render(scene, spp=1)
            assert np.isfinite(img).all(), f"case {case}: non-finite pixels"
            seen["rendered"] += 1
        except REFUSALS:
            seen["refused at render"] += 1
    print("scene tables:", dict(seen), "from", path.name)
    assert seen["rendered"] > 5 and seen["refused"] > 20


def test_render_arguments_at_their_limits(repo, tmp_path):
    scene = gscache.Scene.load(str(small_default_scene(repo, tmp_path, 6, 4)))
    cases = [
        {"spp": 0}, {"spp": -1}, {"spp": 2**32}, {"seed": -1}, {"seed": 2**64},
        {"threads": 0}, {"threads": 1025}, {"threads": -3}, {"max_depth": -2},
        {"max_depth": 2**40}, {"integrator": "nope"}, {"integrator": None, "spp": 1},
        {"spp": 1, "seed": 2**64 - 1, "threads": 1, "max_depth": 0},
    ]
    seen = collections.Counter()
    for kw in cases:
        try:
            img = gscache.render(scene, **kw)
            assert np.isfinite(img).all() and img.shape == (4, 6, 3), kw
            seen["rendered"] += 1
        except REFUSALS:
            seen["refused"] += 1
    print("render arguments:", dict(seen))
    assert seen["rendered"] >= 2 and seen["refused"] >= 9


def test_pickled_partials_with_flipped_bytes_never_merge_wrongly(repo, tmp_path):
    scene = gscache.Scene.load(str(small_default_scene(repo, tmp_path, 6, 4)))
    part = gscache.render_partial(scene, (0, 2), spp=4)
    good = pickle.dumps(part)
    rng = np.random.default_rng(99)
    seen = collections.Counter()
    for case in range(300):
        bad = bytearray(good)
        i = int(rng.integers(len(bad)))
        bad[i] ^= 1 << int(rng.integers(8))
        try:
            p = pickle.loads(bytes(bad))
        except Exception:  # a broken pickle stream: pickle's own errors, all clean
            seen["refused"] += 1
            continue
        # Read: it must be the same partial, byte for byte.
        assert p.to_bytes() == part.to_bytes(), f"case {case}: byte {i} changed what was read"
        seen["read unchanged"] += 1
    print("pickled partials:", dict(seen))
    assert seen["refused"] > 250
