"""Hostile input to the package's entry points: each is refused with a clear message (never an
abort, a hang or a silent black image), with the same limits as the program. Each case once
aborted, hung or returned black (issue 32)."""

import numpy as np
import pytest

import gscache
from conftest import small_default_scene


def small_scene(repo, tmp_path):
    return gscache.Scene.load(str(small_default_scene(repo, tmp_path, 16, 12)))


def test_a_broadcast_view_claiming_petabytes_is_refused_before_the_copy():
    # 10^15 voxels claimed by a 1-byte array: the copy once aborted the interpreter
    # ("memory allocation of 1000000000000000 bytes failed").
    huge = np.broadcast_to(np.zeros(1, np.uint8), (100_000,) * 3)
    with pytest.raises(gscache.GscacheError, match="100000x100000x100000"):
        gscache.Volume.from_array(huge)


def test_a_thread_count_past_the_programs_limit_is_refused(repo, tmp_path):
    scene = small_scene(repo, tmp_path)
    for threads in (0, 100_000):
        with pytest.raises(gscache.GscacheError, match=f"threads = {threads}: expected 1 to 1024"):
            gscache.render(scene, spp=1, threads=threads)


def test_zero_stochastic_samples_is_refused_not_black(repo):
    cloud = gscache.Cloud.read(str(repo / "data/splats/fruit_drops_minimal.ply"))
    with pytest.raises(gscache.GscacheError, match="stochastic = 0"):
        gscache.splat_render(cloud, [0.0, 0.0, 3.0], [0.0, 0.0, 0.0], width=8, height=8, stochastic=0)


def test_a_warm_up_that_would_wrap_is_refused_before_any_work(repo, tmp_path):
    cache = gscache.Cache(small_scene(repo, tmp_path), {"points": 256, "levels": 2})
    for warmup in (2**32 - 1, 2**31):
        with pytest.raises(gscache.GscacheError, match="2\\^32"):
            cache.render(frames=2, warmup=warmup, spp=2)
    assert cache.frames == 0


def test_ctrl_c_stops_splat_trace_with_the_image_so_far(repo):
    # splat_trace once ignored Ctrl-C (the GIL was released with nothing polling). A timer in
    # the child sends SIGINT while a trace of 10^7 estimates a pixel runs; the child installs
    # Python's handler itself (see test_render's Ctrl-C test) and dumps stacks if it hangs.
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(
        f"""
        import faulthandler, os, signal, threading, numpy as np, gscache
        signal.signal(signal.SIGINT, signal.default_int_handler)
        faulthandler.dump_traceback_later(60, exit=True)
        cloud = gscache.Cloud.read({str(repo / "data/splats/fruit_drops_minimal.ply")!r})
        threading.Timer(1.0, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
        try:
            gscache.splat_trace(cloud, [0.76, -0.2, -1.4], [0.76, 0.13, -2.1], width=32,
                                height=24, spp=10_000_000)
            print("not interrupted")
        except gscache.Interrupted as e:
            img = e.image
            print("interrupted", e.samples, bool(np.isfinite(img).all()), float(img.max()) > 0.0)
        """
    )
    try:
        done = subprocess.run(
            [sys.executable, "-c", script], capture_output=True, text=True, timeout=120
        )
    except subprocess.TimeoutExpired as e:
        raise AssertionError(f"the child hung; its stderr: {e.stderr}") from e
    assert done.returncode == 0, done.stderr
    words = done.stdout.split()
    assert words[0] == "interrupted", done.stdout
    assert int(words[1]) > 0 and words[2:] == ["True", "True"], done.stdout


def test_nan_in_a_scene_table_is_named(repo, tmp_path):
    # It once gave the JSON parser's "expected value at line 1 column 63", naming no field.
    volume = gscache.Volume.from_array(np.ones((4, 4, 4), np.float32))
    camera = {"eye": [0, 0, 20], "target": [0, 0, 0], "fov_y": 30, "width": 8, "height": 8}
    transfer = {"window": [0, 1], "points": [{"value": 0, "color": [1, 1, 1], "opacity": float("nan")}]}
    with pytest.raises(ValueError, match=r"transfer\.points\[0\]\.opacity is nan"):
        gscache.Scene(volume, transfer=transfer, camera=camera)
    with pytest.raises(ValueError, match=r"camera\.eye\[2\] is inf"):
        gscache.Scene(volume, transfer={**transfer, "points": []}, camera={**camera, "eye": [0, 0, np.inf]})


def test_a_list_is_refused_with_what_to_do():
    # It once raised AttributeError ('list' object has no attribute 'ndim').
    with pytest.raises(TypeError, match="a list: expected a numpy array.*asarray"):
        gscache.Volume.from_array([[[1]]])


def test_big_endian_arrays_are_read_as_their_values():
    # nibabel gives big-endian NIfTI volumes as `>i2`: they were refused, though int16 is read.
    native = (np.arange(4 * 5 * 6, dtype=np.int16).reshape(4, 5, 6) * 7) - 50
    big = native.astype(">i2")
    a = gscache.Volume.from_array(native)
    b = gscache.Volume.from_array(big)
    # Same shape, dtype and value range (the name says which array it came from).
    assert repr(a).split("shape=")[1] == repr(b).split("shape=")[1], (repr(a), repr(b))
