"""Shards: pickled, merged in any order, equal to the one-process render bit for bit; the
program's and the package's shards merge together; a 2-worker Dask LocalCluster gives the
one-process results."""

import pickle
import random

import numpy as np
import pytest

import gscache
from conftest import import_ome_zarr_package, run_program, small_default_scene


def small_scene_file(repo, tmp_path):
    return small_default_scene(repo, tmp_path, 40, 32)


def bits(a):
    return a.view(np.uint32)


def test_pickled_shards_merge_in_any_order_to_the_render(repo, tmp_path):
    scene = gscache.Scene.load(str(small_scene_file(repo, tmp_path)))
    whole = gscache.render(scene, spp=5)
    parts = [pickle.loads(pickle.dumps(gscache.render_partial(scene, (i, 4), spp=5))) for i in range(4)]
    assert not parts[0].is_complete
    for seed in range(3):
        random.Random(seed).shuffle(parts)
        merged = gscache.Partial.merge_all(parts)
        assert merged.is_complete and merged.ranges == [(0, 5)]
        assert np.array_equal(bits(merged.image()), bits(whole))
    assert (merged.counts() == 5).all()
    with pytest.raises(gscache.GscacheError, match="given twice"):
        parts[0].merge(parts[0])
    other = gscache.render_partial(scene, (0, 4), spp=5, seed=99)
    with pytest.raises(gscache.GscacheError, match="different renders"):
        parts[1].merge(other)
    with pytest.raises(gscache.GscacheError, match="shards are missing"):
        parts[1].image()
    assert parts[1].image(allow_incomplete=True).shape == (32, 40, 3)


def test_program_and_package_shards_merge_together(repo, program, tmp_path):
    path = small_scene_file(repo, tmp_path)
    scene = gscache.Scene.load(str(path))
    a = tmp_path / "program.part"
    done = run_program(program, "render", path, "--spp", "4", "--shard", "0/2", "--partial", a)
    assert done.returncode == 0, done.stderr
    b = gscache.render_partial(scene, (1, 2), spp=4)
    b.write(str(tmp_path / "package.part"))
    merged = gscache.Partial.read(str(a)).merge(b)
    assert np.array_equal(bits(merged.image()), bits(gscache.render(scene, spp=4)))
    # ... and the program merges the package's file.
    out = tmp_path / "merged.exr"
    done = run_program(program, "merge", a, tmp_path / "package.part", "-o", out)
    assert done.returncode == 0, done.stderr
    assert np.array_equal(bits(gscache.read_exr(str(out))), bits(merged.image()))



def test_dask_sharded_render_and_sweep_equal_one_process(repo, tmp_path, client):
    from gscache import distributed as gd

    path = str(small_scene_file(repo, tmp_path))
    scene = gscache.Scene.load(path)
    whole = gscache.render(scene, spp=6)
    image = gd.render_sharded(client, path, 5, spp=6, threads=1)
    assert np.array_equal(bits(image), bits(whole))

    # A recipe function builds a numpy scene on the worker.
    def recipe():
        voxels = np.fromfile(f"{repo}/data/volumes/neghip_64x64x64_uint8.raw", dtype=np.uint8)
        return _neghip_scene(gscache.Volume.from_array(voxels.reshape(64, 64, 64)))

    seeds = [{"seed": s} for s in (1, 2, 3)]
    images = gd.map_sweep(client, recipe, seeds, spp=2, threads=1)
    local = [gscache.render(recipe(), spp=2, seed=s) for s in (1, 2, 3)]
    for a, b in zip(images, local):
        assert np.array_equal(bits(a), bits(b))
    assert not np.array_equal(bits(images[0]), bits(images[1]))


def test_dask_sharded_experiment_equals_one_process(repo, program, tmp_path, client):
    """The program's experiment shards as worker tasks, then the merge: the spp rows of
    runs.csv equal a one-process run's (timed rows differ by nature)."""
    from gscache import distributed as gd

    exp = tmp_path / "tiny.toml"
    exp.write_text(
        f"""
name = "tiny"
scene = "{repo}/data/scenes/default.toml"
width = 32
height = 18
seeds = [1, 2, 3]
output = "{tmp_path}/one"
[reference]
spp = 32
dir = "{tmp_path}/refs"
[budgets]
spp = [1, 4]
[[method]]
name = "nee"
integrator = "nee"
[[method]]
name = "cache"
integrator = "nee"
cache = {{ points = 1000, warmup = 3 }}
"""
    )
    done = run_program(program, "experiment", exp)
    assert done.returncode == 0, done.stderr
    gd.run_experiment_sharded(
        client, str(exp), 3, str(tmp_path / "shards"), program=program, output=str(tmp_path / "merged")
    )

    def spp_rows(folder):
        lines = (folder / "runs.csv").read_text().splitlines()
        # method, budget kind, budget, seed, spp, then seconds: keep all but the timings.
        return sorted(
            (f[:5] + f[7:11]) for f in (l.split(",") for l in lines[1:]) if f[1] == "spp"
        )

    one, merged = spp_rows(tmp_path / "one"), spp_rows(tmp_path / "merged")
    assert len(one) == 2 * 2 * 3
    assert one == merged


def _store_recipe(scene_file, budget):
    """A recipe that opens the scene (and through it the store) within `budget` on the
    worker: nothing of the volume travels."""
    def recipe():
        gscache.set_memory_budget(budget)
        return gscache.Scene.load(scene_file)
    return recipe


def _streamed_on_worker(store, budget):
    import resource
    gscache.set_memory_budget(budget)
    v = gscache.Volume.read(store)
    return v.streamed, v.nbytes, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def test_dask_workers_open_a_shared_store_within_their_budget(repo, program, tmp_path, client):
    """Issue 50: a scene whose volume is an OME-Zarr store in a folder every worker reaches; each
    worker opens the store itself and streams it within a budget of a few bricks; the merged
    image is one process's render of the volume read whole, bit for bit."""
    store = tmp_path / "neghip.ome.zarr"
    done = run_program(program, "convert", str(repo / "data/volumes/neghip_64x64x64_uint8.raw"),
                       str(store), "--chunk", "16", "--max-levels", "1")
    assert done.returncode == 0, done.stderr
    text = small_scene_file(repo, tmp_path).read_text()
    raw = f"{repo}/data/volumes/neghip_64x64x64_uint8.raw"
    assert raw in text
    scene_file = tmp_path / "store.toml"
    scene_file.write_text(text.replace(raw, str(store)))
    whole = gscache.render(gscache.Scene.load(str(small_scene_file(repo, tmp_path))), spp=4)

    from gscache import distributed as gd
    budget = "48K"  # 16^3 bricks of 4 KiB: the page table, the ranges and four bricks
    image = gd.render_sharded(client, _store_recipe(str(scene_file), budget), 4, spp=4,
                              threads=1)
    assert np.array_equal(bits(image), bits(whole))
    for streamed, nbytes, _ in client.gather(
            [client.submit(_streamed_on_worker, str(store), budget, pure=False,
                           workers=[w]) for w in client.scheduler_info()["workers"]]):
        assert streamed and nbytes == 48 * 1024


def _zarr_array_recipe(path, budget):
    """A recipe that opens the zarr array at `path` on the worker and streams it through
    `Volume.from_array` within `budget`: the array itself never travels."""
    def recipe():
        import zarr
        return _neghip_scene(gscache.Volume.from_array(zarr.open_array(path, mode="r"),
                                                       memory_budget=budget))
    return recipe


def _neghip_scene(volume):
    return gscache.Scene(
        volume,
        transfer={"window": [0, 255], "density_scale": 0.6,
                  "points": [{"value": 0.0, "color": [1, 0.8, 0.6], "opacity": 0.0},
                             {"value": 0.4, "color": [0.6, 0.8, 1.0], "opacity": 1.0}]},
        camera={"eye": [60, 45, 95], "target": [0, 0, 0], "fov_y": 38, "width": 24, "height": 20},
        environment=[1.0, 1.0, 1.0],
    )


def test_dask_workers_stream_a_zarr_array_each_opens_itself(repo, tmp_path, client):
    """Issue 50: a recipe opens a zarr array on each worker and streams it within a budget of a
    few bricks (`Volume.from_array`); the shards are of one render (the array's store path
    names its voxels in every process) and merge into the render of the numpy copy, bit for
    bit."""
    zarr = import_ome_zarr_package("zarr")
    voxels = np.fromfile(f"{repo}/data/volumes/neghip_64x64x64_uint8.raw", dtype=np.uint8)
    voxels = voxels.reshape(64, 64, 64)
    path = str(tmp_path / "neghip.zarr")
    stored = zarr.open_array(path, mode="w", shape=voxels.shape, chunks=(16, 16, 16),
                             dtype="uint8")
    stored[:] = voxels
    whole = gscache.render(_neghip_scene(gscache.Volume.from_array(voxels)), spp=4)

    from gscache import distributed as gd
    recipe = _zarr_array_recipe(path, "48K")
    assert recipe()._inner.render_key == recipe()._inner.render_key
    image = gd.render_sharded(client, recipe, 4, spp=4, threads=1)
    assert np.array_equal(bits(image), bits(whole))
