"""Strong scaling of a sharded render on a Dask LocalCluster, and the merge's cost.

    python tools/dask_scaling.py [--size 160] [--spp 256] [--shards 8]

Renders the default scene at SIZE x SIZE with SPP samples: once in this process on one thread,
then as SHARDS shard tasks on a LocalCluster of 1 and of 2 single-threaded worker processes.
Every sharded image is checked equal to the one-process image bit for bit. Prints a Markdown
table (wall-clock seconds, speed-up) and the time to merge the partials. Needs the package and
`distributed` installed (python/run_tests.sh's venv has both; build it with
`maturin develop --release` for timings).
"""

import argparse
import pathlib
import tempfile
import time

import numpy as np
from dask.distributed import Client, LocalCluster

import gscache
from gscache import distributed as gd

REPO = pathlib.Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=160)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--shards", type=int, default=8)
    a = ap.parse_args()
    text = (REPO / "data/scenes/default.toml").read_text()
    text = text.replace("width = 512", f"width = {a.size}").replace("height = 512", f"height = {a.size}")
    text = text.replace('file = "../volumes/', f'file = "{REPO}/data/volumes/')
    tmp = pathlib.Path(tempfile.mkdtemp())
    scene_file = tmp / "scene.toml"
    scene_file.write_text(text)
    scene = gscache.Scene.load(str(scene_file))

    t0 = time.perf_counter()
    one = gscache.render(scene, spp=a.spp, threads=1)
    base = time.perf_counter() - t0
    rows = [("1 process, 1 thread", base)]
    for workers in (1, 2):
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            # Untimed: each worker imports the package and renders once (the first task on a
            # fresh worker also pays for loading the extension and reading the volume).
            gd.render_sharded(client, str(scene_file), 2 * workers, spp=2 * workers, threads=1)
            t0 = time.perf_counter()
            image = gd.render_sharded(client, str(scene_file), a.shards, spp=a.spp, threads=1)
            secs = time.perf_counter() - t0
        assert np.array_equal(image.view(np.uint32), one.view(np.uint32)), "sharded image differs"
        rows.append((f"{workers} worker{'s' if workers > 1 else ''}, {a.shards} shards", secs))

    parts = [gscache.render_partial(scene, (i, a.shards), spp=a.shards) for i in range(a.shards)]
    t0 = time.perf_counter()
    for _ in range(10):
        gscache.Partial.merge_all(parts).image()
    merge_ms = (time.perf_counter() - t0) / 10 * 1e3
    print(f"{a.size}x{a.size}, {a.spp} spp, default scene; every sharded image equals the one-process image")
    print("| setup | seconds | speed-up |\n|---|---|---|")
    for name, secs in rows:
        print(f"| {name} | {secs:.2f} | {base / secs:.2f}x |")
    print(f"merging {a.shards} partials of {a.size}x{a.size} and taking the image: {merge_ms:.1f} ms "
          f"({len(parts[0].to_bytes()) / a.size**2:.0f} bytes a pixel per partial)")


if __name__ == "__main__":
    main()
