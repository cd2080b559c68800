"""Issue 50: a volume from an array that is not numpy (a zarr or dask array, anything numpy can
read a box of), streamed from it a brick at a time within a memory budget and never copied
whole: it renders bit for bit the image of the same voxels copied from numpy, on two render
threads that each take the interpreter's lock to slice it; its faults are named. Skipped where
`zarr` is not installed, unless GSCACHE_REQUIRE_OME_ZARR=1 (CI installs it with ome-zarr)."""

import numpy as np
import pytest

import gscache
from conftest import import_ome_zarr_package

SHAPE = (40, 48, 56)  # z, y, x
DATA = np.random.default_rng(5).integers(1, 4000, size=SHAPE, dtype=np.uint16)
TABLES = dict(
    transfer={"window": [0, 4000], "density_scale": 0.5,
              "points": [{"value": 0.0, "color": [0.9, 0.6, 0.3], "opacity": 0.0},
                         {"value": 1.0, "color": [0.9, 0.6, 0.3], "opacity": 1.0}]},
    camera={"eye": [40, 30, 60], "target": [0, 0, 0], "fov_y": 40, "width": 24, "height": 20},
    environment=[1.0, 1.0, 1.0],
)
# 16^3 bricks of uint16 are 8 KiB: room for a few of them beside the page table and majorant
# ranges, far under the 215 KB the array takes, so it streams and its bricks are evicted and
# read again throughout the render.
BUDGET = 64 * 1024


class Counted:
    """An array that records every box read from it."""

    def __init__(self, array):
        self.array = array
        self.shape = array.shape
        self.dtype = array.dtype
        self.chunks = getattr(array, "chunks", None)
        self.reads = []

    def __getitem__(self, index):
        part = self.array[index]
        self.reads.append(int(np.prod(np.shape(part))))
        return part


def render(volume):
    return gscache.render(gscache.Scene(volume, **TABLES), spp=2, threads=2)


@pytest.mark.parametrize("where", ["folder", "memory"])
def test_a_zarr_array_streams_brick_by_brick_and_renders_as_its_numpy_copy(tmp_path, where):
    """From a store in a folder, and from one that is not a file at all (zarr's in-memory
    store, standing for the object stores zarr reaches through fsspec: the renderer only ever
    slices the array)."""
    zarr = import_ome_zarr_package("zarr")
    store = str(tmp_path / "a.zarr") if where == "folder" else zarr.storage.MemoryStore()
    stored = zarr.open_array(store, mode="w", shape=SHAPE, chunks=(8, 8, 8), dtype="uint16")
    stored[:] = DATA
    counted = Counted(stored)
    streamed = gscache.Volume.from_array(counted, memory_budget=BUDGET)
    whole = gscache.Volume.from_array(DATA)
    assert streamed.streamed and not whole.streamed
    assert streamed.shape == SHAPE and streamed.dtype == "uint16"
    assert streamed.range == whole.range
    expected = render(whole)
    assert expected.mean() > 0.0
    assert np.array_equal(render(streamed), expected), "the streamed render differs"
    # Never a copy of the whole: every read is one 16^3 brick (two 8^3 chunks a side) or the
    # part of one inside the array, and the bricks were read again after eviction.
    assert max(counted.reads) <= 16 ** 3
    bricks = 3 * 3 * 4
    assert len(counted.reads) > bricks, len(counted.reads)
    # Within the budget the array is read whole, as one box, and is the numpy copy's volume.
    counted.reads.clear()
    small = gscache.Volume.from_array(counted)
    assert not small.streamed and counted.reads == [DATA.size]
    assert np.array_equal(small.to_numpy(), DATA)
    assert np.array_equal(render(small), expected)


def test_a_numpy_memmap_larger_than_the_budget_streams_from_its_file(tmp_path):
    """A numpy array has no chunks: it streams in 32^3 bricks (64 KiB of uint16), eight of
    them within a budget of a third of its 1.7 MB."""
    data = np.random.default_rng(6).integers(1, 4000, size=(96, 96, 96), dtype=np.uint16)
    mapped = np.memmap(tmp_path / "voxels.u16", dtype=np.uint16, mode="w+", shape=data.shape)
    mapped[:] = data
    mapped.flush()
    streamed = gscache.Volume.from_array(mapped, memory_budget="600K")
    whole = gscache.Volume.from_array(data)
    assert streamed.streamed and not whole.streamed
    assert np.array_equal(render(streamed), render(whole))


def test_a_dask_array_of_float64_streams_as_its_float32_copy():
    da = pytest.importorskip("dask.array")
    data = DATA.astype(np.float64) / 4000.0
    # Chunks of 8 x 12 x 16 (z, y, x), grouped into bricks of 16 x 24 x 16.
    lazy = da.from_array(data, chunks=(8, 12, 16))
    streamed = gscache.Volume.from_array(lazy, memory_budget=2 * BUDGET)
    whole = gscache.Volume.from_array(data.astype(np.float32))
    assert streamed.streamed and streamed.dtype == "float32"
    tables = dict(TABLES, transfer=dict(TABLES["transfer"], window=[0, 1]))
    images = [gscache.render(gscache.Scene(v, **tables), spp=2, threads=2)
              for v in (whole, streamed)]
    assert images[0].mean() > 0.0
    assert np.array_equal(images[0], images[1]), "the streamed render differs"


class Failing:
    """An array whose reads fail, or return the wrong shape."""

    shape = SHAPE
    dtype = np.dtype("uint16")
    chunks = (8, 8, 8)

    def __init__(self, fault):
        self.fault = fault

    def __getitem__(self, index):
        if self.fault == "raises":
            raise OSError("the disk went away")
        return np.zeros((1, 1, 1), dtype=np.uint16)


@pytest.mark.parametrize("fault, message", [
    ("raises", "the disk went away"),
    ("shape", r"returned shape \[1, 1, 1\], expected \[16, 16, 16\]"),
])
def test_a_failing_array_is_named_with_the_box_it_could_not_read(fault, message):
    # The grid's survey reads every brick when the volume is made.
    with pytest.raises(gscache.GscacheError, match=message) as e:
        gscache.Volume.from_array(Failing(fault), memory_budget=BUDGET)
    assert "Failing of shape (40, 48, 56)" in str(e.value) and "reading voxels" in str(e.value)


class Shaped:
    def __init__(self, shape, dtype):
        self.shape = shape
        self.dtype = np.dtype(dtype)

    def __getitem__(self, index):
        raise AssertionError("a refused array is never read")


@pytest.mark.parametrize("array, message", [
    (Shaped((4, 4), "uint8"), r"2-D test_array_source.Shaped: expected a 3-D array"),
    (Shaped((4, 0, 4), "uint8"), r"shape \(4, 0, 4\): expected each axis 1 to"),
    (Shaped((4, 4, 4), "complex64"), "complex64: expected uint8"),
    (object(), "an object: expected a numpy array of shape"),
])
def test_an_array_that_cannot_be_a_volume_is_refused_by_what_it_lacks(array, message):
    with pytest.raises((gscache.GscacheError, TypeError), match=message):
        gscache.Volume.from_array(array, memory_budget=BUDGET)
