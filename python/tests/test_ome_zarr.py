"""OME-Zarr stores written by the reference Python implementation (PyPI's `ome-zarr` and
`zarr`), read by the program's reader: values, spacing, units, levels, channels and time points
(issue 50), for OME-Zarr 0.4 (Zarr v2) and 0.5 (Zarr v3); a missing chunk is the fill value, a
corrupt one an error naming it; `gscache render STORE` renders one with the automatic scene.
Skipped where `ome-zarr` is not installed, unless GSCACHE_REQUIRE_OME_ZARR=1 (CI)."""

import json
import os
import pathlib
import warnings

import numpy as np
import pytest

import gscache
from conftest import import_ome_zarr_package, run_program

SHAPE = (2, 3, 20, 24, 28)  # t, c, z, y, x
AXES = [
    {"name": "t", "type": "time", "unit": "second"},
    {"name": "c", "type": "channel"},
    {"name": "z", "type": "space", "unit": "micrometer"},
    {"name": "y", "type": "space", "unit": "micrometer"},
    {"name": "x", "type": "space", "unit": "micrometer"},
]
# Level 0 at (z, y, x) = (2, 0.5, 0.25) micrometres; level 1 halves y and x.
TRANSFORMS = [
    [{"type": "scale", "scale": [1, 1, 2.0, 0.5, 0.25]}],
    [{"type": "scale", "scale": [1, 1, 2.0, 1.0, 0.5]}],
]


def _writer():
    zarr = import_ome_zarr_package("zarr")
    fmt = import_ome_zarr_package("ome_zarr.format")
    parse_url = import_ome_zarr_package("ome_zarr.io").parse_url
    write_multiscale = import_ome_zarr_package("ome_zarr.writer").write_multiscale
    return zarr, fmt.FormatV04, fmt.FormatV05, parse_url, write_multiscale


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    """The same 5D uint16 image as OME-Zarr 0.4 and 0.5, two levels, chunks of 8^3."""
    zarr, FormatV04, FormatV05, parse_url, write_multiscale = _writer()
    data = np.random.default_rng(1).integers(1, 4000, size=SHAPE, dtype=np.uint16)
    half = data[:, :, :, ::2, ::2].copy()
    out = {}
    base = tmp_path_factory.mktemp("ome")
    for version, fmt in [("0.4", FormatV04()), ("0.5", FormatV05())]:
        path = base / f"cells_{version}.ome.zarr"
        store = parse_url(str(path), mode="w", fmt=fmt).store
        root = zarr.group(store=store, zarr_format=3 if version == "0.5" else 2)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            write_multiscale([data, half], root, fmt=fmt, axes=AXES,
                             coordinate_transformations=TRANSFORMS,
                             storage_options={"chunks": (1, 1, 8, 8, 8)})
        out[version] = path
    return data, half, out


@pytest.mark.parametrize("version", ["0.4", "0.5"])
def test_a_store_reads_with_its_values_spacing_units_levels_channels_and_times(stores, version):
    data, half, paths = stores
    path = str(paths[version])
    v = gscache.Volume.read(path)
    assert v.shape == (20, 24, 28) and v.dtype == "uint16"
    assert v.spacing == [0.25, 0.5, 2.0], v.spacing  # x, y, z
    assert v.units == "µm"
    assert np.array_equal(v.to_numpy(), data[0, 0])
    picked = gscache.Volume.read(path, channel=2, time=1)
    assert np.array_equal(picked.to_numpy(), data[1, 2])
    coarse = gscache.Volume.read(path, level=1, channel=1)
    assert coarse.shape == (20, 12, 14)
    assert coarse.spacing == [0.5, 1.0, 2.0]
    assert np.array_equal(coarse.to_numpy(), half[0, 1])
    with pytest.raises(gscache.GscacheError, match="channel 3: axis `c` of array `s0` has 3"):
        gscache.Volume.read(path, channel=3)
    with pytest.raises(gscache.GscacheError, match="level 2: the image has 2 levels"):
        gscache.Volume.read(path, level=2)


def _chunk_files(store: pathlib.Path):
    """The level-0 chunk files of a store, largest first (full chunks, not edge ones)."""
    files = [p for p in (store / "s0").rglob("*") if p.is_file()
             and p.name not in (".zarray", ".zattrs", "zarr.json")]
    return sorted(files, key=lambda p: -p.stat().st_size)


@pytest.mark.parametrize("version", ["0.4", "0.5"])
def test_a_missing_chunk_is_the_fill_value_and_a_corrupt_one_is_named(stores, version, tmp_path):
    import shutil

    data, _, paths = stores
    store = tmp_path / "copy.ome.zarr"
    shutil.copytree(paths[version], store)
    # The chunk holding (t, c, z, y, x) = (0, 0, 0..8, 0..8, 0..8): Zarr v3 keys it
    # `c/0/0/0/0/0`, v2 `0/0/0/0/0` (or `0.0.0.0.0` with the old separator).
    level = store / "s0"
    candidates = [level / "c/0/0/0/0/0", level / "0/0/0/0/0", level / "0.0.0.0.0"]
    chunk = next((c for c in candidates if c.is_file()), None)
    assert chunk is not None, sorted(str(p) for p in _chunk_files(store))[:4]
    chunk.unlink()
    v = gscache.Volume.read(str(store)).to_numpy()
    assert (v[:8, :8, :8] == 0).all(), "a missing chunk reads as the fill value, 0"
    assert np.array_equal(v[8:], data[0, 0, 8:]), "the rest is read as written"
    # A truncated chunk: an error that names the array, not a silent zero.
    victim = _chunk_files(store)[0]
    victim.write_bytes(victim.read_bytes()[:5])
    with pytest.raises(gscache.GscacheError, match="array `s0`"):
        gscache.Volume.read(str(store))


def test_bad_metadata_is_refused_by_name(stores, tmp_path):
    import shutil

    _, _, paths = stores
    store = tmp_path / "bad.ome.zarr"
    shutil.copytree(paths["0.5"], store)
    meta = json.loads((store / "zarr.json").read_text())
    meta["attributes"]["ome"]["multiscales"][0]["axes"] = AXES[:2] + AXES[3:]
    (store / "zarr.json").write_text(json.dumps(meta))
    with pytest.raises(gscache.GscacheError, match="bad.ome.zarr"):
        gscache.Volume.read(str(store))
    (store / "zarr.json").write_text("{ not json")
    with pytest.raises(gscache.GscacheError, match="not a Zarr group"):
        gscache.Volume.read(str(store))
    plain = tmp_path / "plain.zarr"
    plain.mkdir()
    with pytest.raises(gscache.GscacheError, match="plain.zarr"):
        gscache.Volume.read(str(plain))


def test_the_program_renders_a_store_with_the_automatic_scene(stores, program, tmp_path):
    _, _, paths = stores
    out = tmp_path / "cells.exr"
    done = run_program(program, "render", str(paths["0.5"]), "--width", "48", "--height", "40",
                       "--spp", "2", "-o", str(out))
    assert done.returncode == 0, done.stderr
    image = gscache.read_exr(str(out))
    assert np.isfinite(image).all() and image.mean() > 0.0
    # Its three channels composited: the first through [transfer], two [[channel]] tables.
    saved = tmp_path / "auto.toml"
    done = run_program(program, "render", str(paths["0.5"]), "--width", "16", "--height", "16",
                       "--spp", "1", "-o", str(tmp_path / "small.exr"), "--save-scene",
                       str(saved))
    assert done.returncode == 0, done.stderr
    import tomllib
    auto = tomllib.loads(saved.read_text())
    assert [c["index"] for c in auto["channel"]] == [1, 2], auto.get("channel")
    # From Python, the same choice: the same channels, the same scene text but its size.
    scene = gscache.Scene.from_volume(str(paths["0.5"]))
    from_python = tomllib.loads(scene.toml)
    assert [c["index"] for c in from_python["channel"]] == [1, 2], scene.toml
    assert from_python["channel"] == auto["channel"]
    assert from_python["transfer"] == auto["transfer"]
    assert np.isfinite(gscache.render(scene, spp=1)).all()


def test_convert_writes_a_store_the_reference_reader_reads(repo, program, tmp_path):
    """`gscache convert` of a NIfTI volume (millimetres) and a raw one, read back by PyPI's
    ome-zarr: level 0 is the volume, level 1 the 2x2x2 block means (numpy's, rounded), the
    scales double per level, the unit is the file's; the program reads its own store back to
    the same voxels; an existing output is not replaced."""
    _writer()
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Reader

    raw = np.fromfile(repo / "data/volumes/neghip_64x64x64_uint8.raw", dtype=np.uint8)
    raw = raw.reshape(64, 64, 64)
    store = tmp_path / "neghip.ome.zarr"
    done = run_program(program, "convert", str(repo / "data/volumes/neghip_64x64x64_uint8.raw"),
                       str(store), "--chunk", "16")
    assert done.returncode == 0, done.stderr
    node = list(Reader(parse_url(str(store)))())[0]
    levels = [np.asarray(level) for level in node.data]
    assert len(levels) == 3 and [lv.shape for lv in levels] == [(64, 64, 64), (32, 32, 32), (16, 16, 16)]
    assert levels[0].dtype == np.uint8 and np.array_equal(levels[0], raw)
    means = raw.reshape(32, 2, 32, 2, 32, 2).astype(np.float64).mean(axis=(1, 3, 5))
    assert np.array_equal(levels[1], np.floor(means + 0.5).astype(np.uint8))
    datasets = node.metadata["coordinateTransformations"]
    assert [d[0]["scale"] for d in datasets] == [[1, 1, 1], [2, 2, 2], [4, 4, 4]]
    assert np.array_equal(gscache.Volume.read(str(store)).to_numpy(), raw)
    again = run_program(program, "convert", str(repo / "data/volumes/neghip_64x64x64_uint8.raw"),
                        str(store))
    assert again.returncode != 0 and "already exists" in again.stderr

    # OME-Zarr 0.4 on Zarr v2, for older readers: the same levels, read by the reference.
    v04 = tmp_path / "neghip04.ome.zarr"
    done = run_program(program, "convert", str(repo / "data/volumes/neghip_64x64x64_uint8.raw"),
                       str(v04), "--chunk", "16", "--ome-version", "0.4")
    assert done.returncode == 0, done.stderr
    assert (v04 / ".zgroup").is_file() and (v04 / "s0" / ".zarray").is_file()
    node = list(Reader(parse_url(str(v04)))())[0]
    levels04 = [np.asarray(level) for level in node.data]
    assert len(levels04) == 3 and all(np.array_equal(a, b) for a, b in zip(levels04, levels))
    assert np.array_equal(gscache.Volume.read(str(v04)).to_numpy(), raw)
    refused = run_program(program, "convert", str(repo / "data/volumes/neghip_64x64x64_uint8.raw"),
                          str(tmp_path / "sharded04.ome.zarr"), "--ome-version", "0.4",
                          "--shard", "128")
    assert refused.returncode != 0 and "sharding needs OME-Zarr 0.5" in refused.stderr

    # A NIfTI in millimetres (nibabel writes it): the unit and the spacing carry over.
    import nibabel as nib
    nii = tmp_path / "mm.nii"
    image = nib.Nifti1Image(raw[:, :40, :50].T.copy(), np.diag([0.5, 0.75, 2.0, 1.0]))
    image.header.set_xyzt_units("mm")
    nib.save(image, str(nii))
    store = tmp_path / "mm.ome.zarr"
    done = run_program(program, "convert", str(nii), str(store))
    assert done.returncode == 0, done.stderr
    node = list(Reader(parse_url(str(store)))())[0]
    axes = node.metadata["axes"]
    assert [a["name"] for a in axes] == ["z", "y", "x"]
    assert all(a.get("unit") == "millimeter" for a in axes), axes
    assert node.metadata["coordinateTransformations"][0][0]["scale"] == [2.0, 0.75, 0.5]
    v = gscache.Volume.read(str(store))
    assert v.units == "mm" and v.spacing == [0.5, 0.75, 2.0]


@pytest.mark.parametrize("version", ["0.4", "0.5"])
def test_a_store_streamed_within_a_small_budget_renders_as_read_whole(stores, version, program,
                                                                       tmp_path):
    """A store written by the reference implementation, streamed within a budget of four of
    its bricks (evicted and read again throughout), renders bit for bit the image of the store
    read whole, from the program (`--memory-budget`) and from Python (`memory_budget=`)."""
    _, _, paths = stores
    path = str(paths[version])
    # 16^3 bricks of uint16 (the 8^3 chunks grouped): 8 KiB each; room for four of them
    # beside the page table and majorant ranges, under the 53 KB the whole level takes, so it
    # streams.
    budget = "40K"
    env = dict(os.environ, GSCACHE_CACHE_DIR=str(tmp_path / "cache"))
    images = {}
    for name, extra in [("whole", []), ("streamed", ["--memory-budget", budget])]:
        out = tmp_path / f"{name}.exr"
        done = run_program(program, "--threads", "2", "render", path, "--width", "40",
                           "--height", "32", "--spp", "2", "-o", str(out), *extra, env=env)
        assert done.returncode == 0, done.stderr
        images[name] = gscache.read_exr(str(out))
    assert images["whole"].mean() > 0.0
    assert np.array_equal(images["whole"], images["streamed"]), "the streamed render differs"

    v = gscache.Volume.read(path, memory_budget=40 * 1024)
    assert v.streamed and not gscache.Volume.read(path).streamed
    assert v.nbytes == 40 * 1024
    with pytest.raises(gscache.GscacheError, match="streamed"):
        v.to_numpy()
    with pytest.raises(gscache.GscacheError, match="memory_budget"):
        gscache.Volume.read(path, memory_budget="lots")


def test_channels_render_together_from_a_scene(stores, program, tmp_path):
    """Issue 50: a store's channels rendered together through `[[channel]]` tables (the
    volume's own channel classified by `[transfer]`, two more by their window, colour and
    opacity): the image differs from the first channel's alone, stays finite, and a channel
    index past the store's axis is refused by name."""
    _, _, paths = stores
    base = f'''
[volume]
file = "{paths["0.5"]}"
[transfer]
window = [0, 4000]
density_scale = 0.5
points = [{{ value = 0.0, color = [0.2, 1.0, 0.2], opacity = 0.0 }},
          {{ value = 1.0, color = [0.2, 1.0, 0.2], opacity = 1.0 }}]
[environment]
radiance = [1.0, 1.0, 1.0]
[camera]
eye = [40.0, 30.0, 60.0]
target = [0.0, 0.0, 0.0]
fov_y = 40.0
width = 40
height = 32
[render]
spp = 4
'''
    channels = '''
[[channel]]
index = 1
window = [0, 4000]
color = [1.0, 0.2, 1.0]
[[channel]]
index = 2
window = [1000, 4000]
color = [0.2, 0.6, 1.0]
opacity = 0.5
'''
    images = {}
    for name, text in [("one", base), ("three", base + channels)]:
        scene = tmp_path / f"{name}.toml"
        scene.write_text(text)
        out = tmp_path / f"{name}.exr"
        done = run_program(program, "render", str(scene), "-o", str(out))
        assert done.returncode == 0, done.stderr
        images[name] = gscache.read_exr(str(out))
    assert np.isfinite(images["three"]).all()
    assert not np.array_equal(images["one"], images["three"])
    # The channels darken the background seen through the medium (more extinction).
    assert images["three"].mean() < images["one"].mean()
    bad = tmp_path / "bad.toml"
    bad.write_text(base + channels.replace("index = 2", "index = 3"))
    done = run_program(program, "render", str(bad), "-o", str(tmp_path / "bad.exr"))
    assert done.returncode != 0 and "channel 3" in done.stderr, done.stderr


def test_channels_from_python(stores):
    """`Scene(volume, channels=[...])` over a store read from Python renders its channels
    together, as the scene file's `[[channel]]` tables do; a numpy volume's channel needs a
    file and is refused without one."""
    _, _, paths = stores
    volume = gscache.Volume.read(str(paths["0.5"]))
    tables = dict(
        transfer={"window": [0, 4000], "density_scale": 0.5,
                  "points": [{"value": 0.0, "color": [0.2, 1.0, 0.2], "opacity": 0.0},
                             {"value": 1.0, "color": [0.2, 1.0, 0.2], "opacity": 1.0}]},
        camera={"eye": [40, 30, 60], "target": [0, 0, 0], "fov_y": 40, "width": 24, "height": 20},
        environment=[1.0, 1.0, 1.0],
    )
    one = gscache.render(gscache.Scene(volume, **tables), spp=2)
    two = gscache.render(gscache.Scene(volume, channels=[
        {"index": 1, "window": [0, 4000], "color": [1.0, 0.2, 1.0]}], **tables), spp=2)
    assert np.isfinite(two).all() and two.mean() < one.mean()
    array = gscache.Volume.from_array(volume.to_numpy())
    with pytest.raises(gscache.GscacheError, match="channel"):
        gscache.Scene(array, channels=[{"index": 1, "window": [0, 1], "color": [1, 1, 1]}],
                      **tables)
