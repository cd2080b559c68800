"""Dask over a shared OME-Zarr store (issue 50): two worker processes open the same store
themselves, each within its own memory budget, render shards of one image, and the merged
image is compared bit for bit with one process's render of the store read whole. Prints each
worker's peak resident memory (the kernel's ru_maxrss) against its budget.

    python tools/dask_store_bench.py SCENE.toml --budget 256M --shards 4 --spp 2

SCENE names the store (`gscache bench stream --voxels 1024` writes one and its scene).
A benchmark, not a test: BENCHMARKS.md quotes it with the machine.
"""

import argparse
import resource
import time

import numpy as np

import gscache
from gscache import distributed as gd


def recipe_for(scene_file: str, budget: str):
    def recipe():
        gscache.set_memory_budget(budget)
        return gscache.Scene.load(scene_file)
    return recipe


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scene")
    p.add_argument("--budget", default="256M")
    p.add_argument("--shards", type=int, default=4)
    p.add_argument("--spp", type=int, default=2)
    p.add_argument("--workers", type=int, default=2)
    a = p.parse_args()
    import distributed

    with distributed.LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        workers = list(client.scheduler_info()["workers"])
        before = client.run(peak_rss_mib)
        t = time.perf_counter()
        image = gd.render_sharded(client, recipe_for(a.scene, a.budget), a.shards,
                                  spp=a.spp, threads=1)
        seconds = time.perf_counter() - t
        after = client.run(peak_rss_mib)
    # One process, the store read whole (a budget it fits in).
    gscache.set_memory_budget("64G")
    t = time.perf_counter()
    whole = gscache.render(gscache.Scene.load(a.scene), spp=a.spp, threads=1)
    one = time.perf_counter() - t
    same = np.array_equal(image.view(np.uint32), whole.view(np.uint32))
    print(f"{a.workers} workers x 1 thread, {a.shards} shards, {a.spp} spp, budget {a.budget} a "
          f"worker: {seconds:.1f} s (one process, read whole, 1 thread: {one:.1f} s); merged "
          f"image bit for bit the one-process render: {same}")
    print("| worker | peak RSS before, MiB | peak RSS after, MiB |")
    print("|---|---|---|")
    for w in workers:
        print(f"| {w} | {before[w]:.0f} | {after[w]:.0f} |")
    if not same:
        raise SystemExit("the merged image differs from the one-process render")


if __name__ == "__main__":
    main()
