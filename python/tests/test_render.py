"""Renders from Python against the program's, bit for bit; volumes from numpy; progress with a
total, Ctrl-C and errors."""

import os
import pathlib
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import gscache
from conftest import run_program, small_default_scene

try:
    import tomllib
except ImportError:  # Python < 3.11
    tomllib = None

SIZE = ["--width", "48", "--height", "40"]


def program_exr(program, tmp_path, scene, *flags):
    out = tmp_path / "program.exr"
    done = run_program(program, "render", scene, *SIZE, *flags, "-o", out)
    assert done.returncode == 0, done.stderr
    return gscache.read_exr(str(out))


def default_tables(repo):
    """The default scene's tables and its volume as numpy reads it (x fastest on disk)."""
    if tomllib is None:
        pytest.skip("tomllib needs Python 3.11")
    tables = tomllib.loads((repo / "data/scenes/default.toml").read_text())
    raw = np.fromfile(repo / "data/volumes/neghip_64x64x64_uint8.raw", dtype=np.uint8)
    return tables, raw.reshape(64, 64, 64)


def scene_from_tables(tables, volume, width=48, height=40):
    camera = dict(tables["camera"], width=width, height=height)
    return gscache.Scene(
        volume,
        transfer=tables["transfer"],
        camera=camera,
        lights=tables["light"],
        environment=tables["environment"]["radiance"],
        phase=tables["phase"],
        render=tables["render"],
        output=tables["output"],
        spacing=tables["volume"]["spacing"],
    )


def test_numpy_volume_renders_the_programs_image_bit_for_bit(repo, program, tmp_path):
    tables, voxels = default_tables(repo)
    scene = scene_from_tables(tables, gscache.Volume.from_array(voxels))
    assert isinstance(scene, gscache.Scene) and (scene.width, scene.spp) == (48, 64)
    image = gscache.render(scene, spp=3)
    expect = program_exr(program, tmp_path, "data/scenes/default.toml", "--spp", "3")
    assert image.shape == (40, 48, 3) and image.dtype == np.float32
    assert image.mean() > 0.01
    assert np.array_equal(image.view(np.uint32), expect.view(np.uint32))


def test_scene_file_threads_and_overrides_match_the_program(repo, program, tmp_path):
    full = gscache.Scene.load(str(repo / "data/scenes/default.toml"))
    assert (full.width, full.height, full.spp) == (512, 512, 64)
    # A smaller copy of the scene file, so the test stays fast.
    small = small_default_scene(repo, tmp_path, 48, 40)
    scene = gscache.Scene.load(str(small))
    for kw, flags in [
        ({"spp": 2}, ["--spp", "2"]),
        ({"spp": 2, "seed": 7, "integrator": "uniform", "max_depth": 3},
         ["--spp", "2", "--seed", "7", "--integrator", "uniform", "--max-depth", "3"]),
    ]:
        expect = program_exr(program, tmp_path, small, *flags)
        for threads in (1, 2):
            image = gscache.render(scene, threads=threads, **kw)
            assert np.array_equal(image.view(np.uint32), expect.view(np.uint32)), (kw, threads)


def test_clipping_from_python_is_the_programs(repo, program, tmp_path):
    """A clip box and plane given to ``Scene.clipped``, or as the ``clip`` table, render the
    program's ``--clip-box``/``--clip-plane`` image bit for bit; clipping changes the image and
    the render key, and clearing it gives the unclipped image back."""
    tables, voxels = default_tables(repo)
    volume = gscache.Volume.from_array(voxels)
    scene = scene_from_tables(tables, volume)
    box = ([-40.0, -40.0, -40.0], [40.0, 40.0, 8.0])
    plane = ([0.0, 0.0, 0.0], [1.0, 0.5, 0.0])
    clipped = scene.clipped(box=box, planes=[plane])
    assert clipped.clip == {"box": {"min": box[0], "max": box[1]},
                            "plane": [{"point": plane[0], "normal": plane[1]}]}
    assert scene.clip == {}, "the original scene is not changed"
    assert clipped.render_key != scene.render_key
    image = gscache.render(clipped, spp=2)
    expect = program_exr(program, tmp_path, "data/scenes/default.toml", "--spp", "2",
                         "--clip-box=-40,-40,-40,40,40,8", "--clip-plane", "0,0,0,1,0.5,0")
    assert np.array_equal(image.view(np.uint32), expect.view(np.uint32))
    plain = gscache.render(scene, spp=2)
    assert not np.array_equal(image, plain)
    assert np.array_equal(gscache.render(clipped.clipped(), spp=2), plain)
    camera = dict(tables["camera"], width=48, height=40)
    as_table = gscache.Scene(volume, transfer=tables["transfer"], camera=camera,
                             lights=tables["light"], environment=tables["environment"]["radiance"],
                             phase=tables["phase"], render=tables["render"],
                             output=tables["output"], spacing=tables["volume"]["spacing"],
                             clip=clipped.clip)
    assert np.array_equal(gscache.render(as_table, spp=2).view(np.uint32), expect.view(np.uint32))
    with pytest.raises(gscache.GscacheError, match="min < max"):
        scene.clipped(box=([0, 0, 0], [1, 1, 0]))


@pytest.mark.parametrize("dtype", ["uint8", "int8", "uint16", "int16", "float32"])
def test_every_reader_dtype_is_kept_and_strides_do_not_matter(repo, dtype):
    tables, voxels = default_tables(repo)
    data = voxels.astype(dtype) if dtype != "int8" else (voxels // 2).astype(np.int8)
    volume = gscache.Volume.from_array(data)
    assert volume.dtype == dtype and volume.shape == (64, 64, 64)
    assert volume.nbytes == data.nbytes
    # The same voxels through a strided view (every other x of a wider array).
    wide = np.zeros((64, 64, 128), dtype=data.dtype)
    wide[:, :, ::2] = data
    strided = gscache.Volume.from_array(wide[:, :, ::2])
    tables["transfer"]["window"] = [float(data.min()), float(data.max())]
    a = gscache.render(scene_from_tables(tables, volume, 24, 20), spp=1)
    b = gscache.render(scene_from_tables(tables, strided, 24, 20), spp=1)
    assert np.array_equal(a.view(np.uint32), b.view(np.uint32))
    assert a.mean() > 0.0


def test_unsupported_arrays_are_refused_with_what_to_do():
    with pytest.raises(TypeError, match="float64.*astype"):
        gscache.Volume.from_array(np.zeros((4, 4, 4)))
    with pytest.raises(TypeError, match="2-D array"):
        gscache.Volume.from_array(np.zeros((4, 4), dtype=np.float32))
    with pytest.raises(gscache.GscacheError, match="finite"):
        gscache.Volume.from_array(np.full((2, 2, 2), np.nan, dtype=np.float32))


def test_progress_counts_every_sample_and_its_exception_stops_the_render(repo):
    tables, voxels = default_tables(repo)
    scene = scene_from_tables(tables, gscache.Volume.from_array(voxels))
    seen = []
    gscache.render(scene, spp=4, progress=seen.append)
    assert seen and seen[-1] == 48 * 40 * 4
    assert seen == sorted(seen)
    # A callable of two arguments is given the total too.
    totals = []
    gscache.render(scene, spp=4, progress=lambda done, total: totals.append((done, total)))
    assert totals and totals[-1] == (48 * 40 * 4, 48 * 40 * 4)
    assert {t for _, t in totals} == {48 * 40 * 4}
    cache = gscache.Cache(scene, {"levels": 2})
    frames = []
    cache.render(2, warmup=3, spp=1, progress=lambda done, total: frames.append((done, total)))
    assert frames[-1] == (48 * 40 * 5, 48 * 40 * 5), frames[-3:]

    class Stop(Exception):
        pass

    def stop(n):
        raise Stop(n)

    with pytest.raises(Stop):
        gscache.render(scene, spp=100_000, progress=stop)


@pytest.mark.parametrize(
    "call",
    [
        "gscache.render(scene, spp=100_000, progress=progress)",
        # Issue 48, item 8: an interrupted shard raised Interrupted with no image at all.
        "gscache.render_partial(scene, (0, 2), spp=200_000, progress=progress)",
    ],
)
def test_ctrl_c_raises_interrupted_with_the_partial_image(repo, call):
    # SIGINT is sent from the progress callback once samples exist, so it always lands inside
    # the render whatever the machine's load. The child installs Python's Ctrl-C handler itself:
    # a process started in the background by a non-interactive shell inherits SIGINT ignored,
    # and Python then installs none (the test hung that way when the suite ran under `cmd &`).
    # faulthandler dumps every thread's stack if the child hangs, so a failure says where.
    script = textwrap.dedent(
        f"""
        import faulthandler, os, signal, numpy as np, gscache
        signal.signal(signal.SIGINT, signal.default_int_handler)
        faulthandler.dump_traceback_later(60, exit=True)
        scene = gscache.Scene.load({str(repo / "data/scenes/default.toml")!r})
        sent = []
        def progress(done):
            if done > 0 and not sent:
                sent.append(done)
                os.kill(os.getpid(), signal.SIGINT)
        try:
            {call}
            print("not interrupted")
        except gscache.Interrupted as e:
            img = e.image
            print("interrupted", e.samples, bool(np.isfinite(img).all()), float(img.mean()) > 0.0)
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


def test_bad_input_gives_the_programs_message(program, tmp_path):
    missing = tmp_path / "missing.toml"
    done = run_program(program, "render", missing)
    assert done.returncode != 0
    with pytest.raises(gscache.GscacheError) as e:
        gscache.Scene.load(str(missing))
    assert done.stderr.strip() == "error: " + str(e.value).strip()

    bad = tmp_path / "bad.toml"
    bad.write_text("[volume]\nfile = 'x.raw'\n")
    done = run_program(program, "render", bad)
    with pytest.raises(gscache.GscacheError) as e:
        gscache.Scene.load(str(bad))
    assert "missing field `transfer`" in str(e.value)
    assert done.stderr.strip() == "error: " + str(e.value).strip()

    volume = gscache.Volume.from_array(np.ones((4, 4, 4), dtype=np.uint8))
    with pytest.raises(gscache.GscacheError, match="unknown field"):
        gscache.Scene(volume, transfer={"density_scale": 1.0, "pointz": []}, camera={})
    with pytest.raises(gscache.GscacheError, match="integrator"):
        scene = gscache.Scene(
            volume,
            transfer={"density_scale": 1.0, "points": [{"value": 0, "color": [1, 1, 1], "opacity": 1}]},
            camera={"eye": [0, 0, 9], "target": [0, 0, 0], "fov_y": 40, "width": 8, "height": 8},
        )
        gscache.render(scene, spp=1, integrator="bidirectional")


def test_a_rendered_image_shows_itself_as_png(repo, tmp_path):
    """``render`` gives an ``Image``: still a float32 numpy array, and ``_repr_png_`` draws it
    tone-mapped by the program's own code (the same bytes ``write_png`` writes)."""
    scene = gscache.Scene.load(str(small_default_scene(repo, tmp_path, 24, 16)))
    image = gscache.render(scene, spp=2)
    assert isinstance(image, np.ndarray) and image.dtype == np.float32
    assert image.shape == (16, 24, 3)
    png = image._repr_png_()
    assert png.startswith(b"\x89PNG\r\n\x1a\n")
    gscache.write_png(str(tmp_path / "direct.png"), np.asarray(image), scene.exposure,
                      scene.tonemap)
    assert png == (tmp_path / "direct.png").read_bytes()
    assert (image * 2.0)._repr_png_() != png
