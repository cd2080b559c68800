"""Renders and sweeps scaled out on Dask (``distributed``): a ``LocalCluster`` on one machine,
``dask_jobqueue``'s SLURM or PBS clusters on a cluster (docs/python.md has a worked example).

A render is split into shards (ranges of every pixel's sample indices). Each shard is a pure
function of the scene and settings, so any worker may run it; its result is a ``Partial``
(exact fixed-point sums), and partials merge, in any order or tree, into the image one process
would render, bit for bit. Nothing here schedules: Dask does.

A movie is split into parts, ranges of its frames, each a task that writes its frames into a
folder of its own under the movie's (a folder every worker can reach); the client then moves
them into the movie in order. Without a cache the frames are one process's, bit for bit (each
frame's samples are fixed by its place in the movie); with a cache each part after the first
trains on the ``overlap`` frames before it, so its first frames differ from one process's (the
seam; docs/python.md states what was measured).

Scenes hold their volume and do not travel between processes. A shard task builds its scene on
the worker from a *recipe*: a scene file's path, or a function of no arguments that returns a
``Scene`` (it is pickled with cloudpickle, so a closure over a small array or a file name is
fine; a closure over a gigavoxel array ships that array to every task).
"""

from __future__ import annotations

from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Union

import numpy as np

from . import Partial, Scene, _config_json, _gscache, _movie_spec, render, render_partial

Recipe = Union[str, Callable[[], Any]]


def _scene(recipe: Recipe) -> Any:
    if callable(recipe):
        return recipe()
    return Scene.load(str(recipe))


def _shard_task(recipe: Recipe, index: int, count: int, options: Mapping[str, Any]) -> Partial:
    return render_partial(_scene(recipe), (index, count), **options)


def _merge_pair(a: Partial, b: Partial) -> Partial:
    return a.merge(b)


def _image(p: Partial, allow_incomplete: bool) -> np.ndarray:
    return p.image(allow_incomplete)


def submit_shards(client: Any, recipe: Recipe, shards: int, **options: Any) -> List[Any]:
    """Submits the ``shards`` shard tasks of one render; returns their futures (each a
    ``Partial``). ``options`` are ``render_partial``'s: ``spp``, ``seed``, ``integrator``,
    ``max_depth``, ``threads`` (per task; default: all of the worker's cores)."""
    if shards < 1:
        raise ValueError(f"shards = {shards}: expected at least 1")
    return [
        client.submit(_shard_task, recipe, i, shards, dict(options), pure=False)
        for i in range(shards)
    ]


def tree_merge(client: Any, futures: Sequence[Any]) -> Any:
    """Merges partials pairwise on the workers (log2(n) rounds, no partial copied to the
    client); returns the future of the merged ``Partial``."""
    level = list(futures)
    if not level:
        raise ValueError("no partials to merge")
    while len(level) > 1:
        nxt = [client.submit(_merge_pair, a, b) for a, b in zip(level[0::2], level[1::2])]
        if len(level) % 2:
            nxt.append(level[-1])
        level = nxt
    return level[0]


def render_sharded(
    client: Any,
    recipe: Recipe,
    shards: int,
    *,
    allow_incomplete: bool = False,
    **options: Any,
) -> np.ndarray:
    """Renders ``recipe``'s scene in ``shards`` shard tasks on ``client``'s workers and returns
    the merged image: float32 (height, width, 3), equal bit for bit to ``gscache.render`` of
    the same scene and options in one process."""
    from distributed import wait

    futures = submit_shards(client, recipe, shards, **options)
    # The merges are submitted once every shard is done: submitted with the shards, they make
    # the scheduler place sibling shards together for locality, and two workers then took
    # 4.6-4.8 s where they take 4.0 s this way (tools/dask_scaling.py, 160x160, 8 shards).
    wait(futures)
    merged = tree_merge(client, futures)
    return client.submit(_image, merged, allow_incomplete).result()


def _sweep_task(recipe: Recipe, options: Mapping[str, Any]) -> np.ndarray:
    return render(_scene(recipe), **options)


def map_sweep(
    client: Any,
    recipe: Recipe,
    points: Sequence[Mapping[str, Any]],
    **common: Any,
) -> List[np.ndarray]:
    """Renders one whole image per sweep point (a dict of ``render`` options, e.g.
    ``{"seed": 3}`` or ``{"integrator": "uniform", "spp": 256}``; ``common`` applies to all) as
    independent tasks; returns the images in the points' order."""
    futures = [
        client.submit(_sweep_task, recipe, {**common, **dict(p)}, pure=False) for p in points
    ]
    return client.gather(futures)


def _resolve_program(program: Optional[str]) -> str:
    """The program to run where this is called (a worker or the client): the one given, else
    the package's (``gscache.program()``: $GSCACHE_BIN, or the one the wheel installed)."""
    if program is not None:
        return program
    from ._program import program as installed

    found = installed()
    if found is None:
        raise RuntimeError(
            "no gscache program here: the package was installed without it (an editable "
            "install, or GSCACHE_WHEEL_PROGRAM=0). Install it with `pip install .` on every "
            "worker, set GSCACHE_BIN, or pass program=PATH."
        )
    return found


def _run_program(command: list) -> str:
    import subprocess

    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({done.returncode}): {done.stderr.strip()}")
    return done.stdout


def _experiment_shard(program: Optional[str], experiment: str, index: int, count: int, out: str) -> str:
    command = [_resolve_program(program), "-q", "experiment", experiment]
    _run_program(command + ["--shard", f"{index}/{count}", "--shard-output", out])
    return out


def run_experiment_sharded(
    client: Any,
    experiment: str,
    shards: int,
    folder: str,
    *,
    program: Optional[str] = None,
    output: Optional[str] = None,
) -> Dict[str, Any]:
    """Runs ``gscache experiment EXPERIMENT --shard i/n`` for every shard as worker tasks
    (each writes ``folder/shard-i-of-n.json``; the folder must be shared by the workers),
    then ``gscache experiment merge`` on the client: the report a single run would write.
    ``program`` is the ``gscache`` binary's path; by default each machine runs the one its
    package installed (``gscache.program()``), whatever its PATH."""
    import os

    os.makedirs(folder, exist_ok=True)
    outs = [os.path.join(folder, f"shard-{i}-of-{shards}.json") for i in range(shards)]
    futures = [
        client.submit(_experiment_shard, program, experiment, i, shards, o, pure=False)
        for i, o in enumerate(outs)
    ]
    client.gather(futures)
    cmd = [_resolve_program(program), "-q", "experiment", "merge", experiment, *outs]
    if output is not None:
        cmd += ["--output", output]
    return {"shards": outs, "stdout": _run_program(cmd)}


def _movie_part(recipe: Recipe, folder: str, spec: str, cache_json: Optional[str],
                part: tuple, threads: Optional[int]) -> str:
    scene = _scene(recipe)
    _, interrupted, _ = _gscache._movie(
        scene._inner, folder, spec, cache_json, True, part, threads, None
    )
    if interrupted:
        raise RuntimeError(f"the movie's part {part} in {folder} was interrupted")
    return folder


def movie(
    client: Any,
    recipe: Recipe,
    folder: str,
    frames: int = 120,
    *,
    parts: Optional[int] = None,
    overlap: int = 8,
    fps: float = 30.0,
    turntable_degrees: float = 360.0,
    keys: Optional[Sequence[Mapping[str, Any]]] = None,
    spp: Optional[int] = None,
    warmup: int = 0,
    cache: Any = None,
    denoise: Any = None,
    reference_spp: Optional[int] = None,
    video: Optional[str] = "mp4",
    threads: Optional[int] = None,
) -> str:
    """``gscache.movie`` split across ``client``'s workers: ``parts`` ranges of frames (default:
    one per worker), each a task writing into ``folder/parts/``, then merged into ``folder`` in
    order on the client (``folder`` must be shared with the workers) and encoded (``video``).
    A sample budget per frame (``spp``) is needed: a time budget's frames depend on every frame
    before. Without a cache the frames equal one process's bit for bit. With a cache, each part
    after the first trains on the ``overlap`` frames before it (rendered again, not written)
    after the scene's ``warmup``; the other options are ``gscache.movie``'s. Returns the
    folder."""
    import os

    scene = _scene(recipe)
    spec = _movie_spec(frames, fps, turntable_degrees, keys, spp, None, warmup, denoise,
                       reference_spp, scene.spp)
    cache_json = _config_json({} if cache is True else cache) if cache else None
    if parts is None:
        parts = max(1, len(client.scheduler_info().get("workers", {})))
    parts = max(1, min(int(parts), int(frames)))
    bounds = [round(i * frames / parts) for i in range(parts + 1)]
    os.makedirs(os.path.join(folder, "parts"), exist_ok=True)
    folders = []
    futures = []
    for first, last in zip(bounds[:-1], bounds[1:]):
        part_folder = os.path.join(folder, "parts", f"{first:06d}-{last:06d}")
        folders.append(part_folder)
        futures.append(client.submit(
            _movie_part, recipe, part_folder, spec, cache_json, (first, last, overlap), threads,
            pure=False,
        ))
    client.gather(futures)
    _gscache._merge_movie(scene._inner, folder, spec, folders, cache_json)
    try:
        os.rmdir(os.path.join(folder, "parts"))
    except OSError:
        pass
    if video is not None:
        _gscache._encode_movie(scene._inner, folder, spec, video, cache_json)
    return folder
