"""Movies from Python: ``gscache.movie`` makes the program's frames bit for bit, and
``gscache.distributed.movie`` over a 2-worker Dask LocalCluster makes one process's frames bit
for bit with NEE; with the cache, its first part is one process's and the seam (the first frame
of the second part, trained on fewer frames) differs from one process's frame by less than
another seed's frame does."""

import numpy as np
import pytest

import gscache
from conftest import run_program, small_default_scene


def bits(a):
    return np.ascontiguousarray(a, dtype=np.float32).view(np.uint32)


def frames_of(folder, n):
    return gscache.movie_frames(str(folder), n)


def test_python_movie_equals_the_programs(repo, program, tmp_path):
    path = small_default_scene(repo, tmp_path, 32, 18)
    scene = gscache.Scene.load(str(path))
    folder, frames = gscache.movie(scene, tmp_path / "py", 4, spp=2, turntable_degrees=40,
                                   video=None, return_frames=True)
    assert frames.shape == (4, 18, 32, 3)
    done = run_program(program, "movie", path, "-o", tmp_path / "cli", "--frames", "4", "--spp",
                       "2", "--turntable-degrees", "40", "--video", "none")
    assert done.returncode == 0, done.stderr
    assert np.array_equal(bits(frames), bits(frames_of(tmp_path / "cli", 4)))
    # The frames turn: not one image four times.
    assert not np.array_equal(bits(frames[0]), bits(frames[3]))
    # The folder is the movie's: a second call without resume is refused, naming it.
    with pytest.raises(gscache.GscacheError, match="holds a movie already"):
        gscache.movie(scene, folder, 4, spp=2, turntable_degrees=40, video=None)
    # With the cache too (a warm-up along the path), bit for bit.
    _, cached = gscache.movie(scene, tmp_path / "pyc", 3, spp=2, warmup=2, video=None,
                              cache={"points": 500}, return_frames=True)
    done = run_program(program, "movie", path, "-o", tmp_path / "clic", "--frames", "3",
                       "--spp", "2", "--warmup", "2", "--cache", "--cache-points", "500",
                       "--video", "none")
    assert done.returncode == 0, done.stderr
    assert np.array_equal(bits(cached), bits(frames_of(tmp_path / "clic", 3)))



def test_dask_movie_equals_one_process_and_states_its_seam(repo, tmp_path, client):
    from gscache import distributed as gd

    path = str(small_default_scene(repo, tmp_path, 32, 18))
    scene = gscache.Scene.load(path)
    n = 6
    one = frames_of(gscache.movie(scene, tmp_path / "one", n, spp=2, turntable_degrees=60,
                                  video=None, threads=1), n)
    split = gd.movie(client, path, str(tmp_path / "split"), n, parts=2, spp=2,
                     turntable_degrees=60, video=None, threads=1)
    assert np.array_equal(bits(frames_of(split, n)), bits(one))
    assert not (tmp_path / "split" / "parts").exists()

    # The cache: part 0 is one process's; the seam frame (3) differs from one process's by
    # the cache's state alone (the same samples), which must cost less than another seed.
    cache = {"points": 500}
    opts = dict(spp=2, turntable_degrees=60, warmup=4, cache=cache, video=None, threads=1)
    one_c = frames_of(gscache.movie(scene, tmp_path / "onec", n, **opts), n)
    split_c = frames_of(gd.movie(client, path, str(tmp_path / "splitc"), n, parts=2, overlap=2,
                                 **opts), n)
    assert np.array_equal(bits(split_c[:3]), bits(one_c[:3]))
    other = gscache.Scene.load(path)
    text = open(path).read().replace("seed = 1", "seed = 2")
    other_path = tmp_path / "seed2.toml"
    other_path.write_text(text)
    other = gscache.Scene.load(str(other_path))
    seed2 = frames_of(gscache.movie(other, tmp_path / "seed2", n, **opts), n)

    def rel(a, b):
        return float(np.mean((a - b) ** 2 / (b ** 2 + 0.01)))

    seam, noise = rel(split_c[3], one_c[3]), rel(seed2[3], one_c[3])
    print(f"seam frame: relMSE {seam:.3e} against one process's; another seed's {noise:.3e}")
    assert 0 < seam < noise
