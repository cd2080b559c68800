"""gscache: volume path tracing with a Gaussian radiance cache (GSCache, Bauer et al. 2025).

The renderer of the ``gscache`` program, from Python:

- ``Volume.from_array`` (numpy, shape (nz, ny, nx); uint8, int8, uint16, int16 or float32,
  kept in its own type; a zarr or dask array, an h5py dataset or any array numpy can read a
  box of is streamed from it a brick at a time when larger than ``memory_budget``, never
  copied whole) or ``Volume.read`` (raw, NRRD, VTK, NIfTI files, OME-Zarr stores with
  ``level``, ``channel`` and ``time``);
- ``Scene(volume, transfer=..., camera=..., lights=...)`` with the scene format's tables
  (docs/scene-format.md), or ``Scene.load("scene.toml")``;
- ``render(scene, spp=...)`` -> float32 array (height, width, 3); Ctrl-C raises
  ``Interrupted``, which carries the image rendered so far;
- ``render_partial(scene, shard=(i, n))`` -> ``Partial``: shards of one render merge into
  the one-process image bit for bit (``gscache.distributed`` runs them on Dask);
- ``Cache``: the radiance cache, trained frame after frame;
- ``Cloud``, ``splat_render``, ``splat_trace``: 3D Gaussian clouds;
- ``read_exr``, ``write_exr``, ``write_png``;
- ``denoise(image, albedo=..., normal=...)``: Intel Open Image Denoise (``pip install pyoidn``),
  guided by the feature buffers ``render(..., features=True)`` returns;
- ``movie(scene, folder, frames=...)``: ``gscache movie``, numbered frames and a video
  (``gscache.distributed.movie`` splits it across Dask workers).

Errors the renderer refuses are ``GscacheError``, with the message the program prints.
"""

from __future__ import annotations

import json
import pathlib
import math
from typing import Any, Callable, Mapping, Optional, Sequence, Tuple

import numpy as np

from ._gscache import (
    Cloud,
    GscacheError,
    Partial,
    Volume,
    __version__,
    read_exr,
    set_memory_budget,
    splat_render,
    write_exr,
    write_png,
)
from . import _gscache
from ._program import program

__all__ = [
    "program",
    "Cache",
    "Cloud",
    "GscacheError",
    "Image",
    "Viewer",
    "view",
    "Interrupted",
    "Partial",
    "Scene",
    "Volume",
    "__version__",
    "denoise",
    "movie",
    "read_exr",
    "render",
    "render_partial",
    "set_memory_budget",
    "splat_render",
    "splat_trace",
    "write_exr",
    "write_png",
]

Progress = Callable[..., Any]  # progress(done, total) or progress(done)


class Interrupted(KeyboardInterrupt):
    """Ctrl-C stopped a render. ``image`` holds what was rendered (each pixel the mean of the
    samples it received, at least one each; for ``render_partial``, of the shard's samples, as
    an image, not a ``Partial``, which must hold whole sample ranges; for ``Cache.render``, the
    frames' image so far) and ``samples`` how many samples were taken."""

    def __init__(self, image: Optional[np.ndarray], samples: int):
        super().__init__(f"render interrupted after {samples} samples")
        self.image = image
        self.samples = samples


def _drop_none(d: Mapping[str, Any]) -> dict:
    return {k: v for k, v in d.items() if v is not None}


class Scene:
    """A scene ready to render: the scene format's tables (docs/scene-format.md) around a
    ``Volume``, or a scene file (``Scene.load``).

    ``transfer`` (``window``, ``density_scale``, ``points`` or ``preset``), ``camera`` (``eye``,
    ``target``, ``up``, ``fov_y``, ``width``, ``height``), ``lights`` (each ``center``,
    ``radius``, ``radiance``), ``environment`` (RGB radiance), ``phase``, ``render`` (``spp``,
    ``max_depth``, ``integrator``, ``seed``, ``rr_start_depth``), ``output`` (``exposure``,
    ``tonemap``), ``clip`` (``box`` as ``{"min": [x, y, z], "max": [x, y, z]}`` and ``plane``
    as a list of ``{"point": ..., "normal": ...}``, the side the normal points to cut away),
    ``channels`` (each ``index``, ``window``, ``color``, optional ``opacity``,
    ``density_scale`` and ``file``: more channels rendered together, as ``[[channel]]``
    tables; from the volume's own file where it was read from one);
    ``spacing``, ``origin``, ``filter`` and ``macrocell`` place the volume as the ``[volume]``
    table does. Preset paths are relative to the working folder. The tables are
    parsed by the program's own code, so a mistake gets the program's message."""

    def __init__(
        self,
        volume: Volume,
        *,
        transfer: Mapping[str, Any],
        camera: Mapping[str, Any],
        lights: Sequence[Mapping[str, Any]] = (),
        environment: Optional[Sequence[float]] = None,
        phase: Optional[Mapping[str, Any]] = None,
        render: Optional[Mapping[str, Any]] = None,
        output: Optional[Mapping[str, Any]] = None,
        clip: Optional[Mapping[str, Any]] = None,
        channels: Sequence[Mapping[str, Any]] = (),
        spacing: Optional[Sequence[float]] = None,
        origin: Optional[Sequence[float]] = None,
        filter: Optional[str] = None,
        macrocell: Optional[int] = None,
    ):
        tables = {
            "volume": _drop_none(
                {
                    "file": "<array>",
                    "spacing": spacing,
                    "origin": origin,
                    "filter": filter,
                    "macrocell": macrocell,
                }
            ),
            "transfer": dict(transfer),
            "camera": dict(camera),
            "light": [dict(l) for l in lights],
        }
        if channels:
            tables["channel"] = [dict(c) for c in channels]
        if environment is not None:
            tables["environment"] = {"radiance": environment}
        for name, table in (
            ("phase", phase),
            ("render", render),
            ("output", output),
            ("clip", clip),
        ):
            if table is not None:
                tables[name] = dict(table)
        _finite_tables(tables, "")
        self._inner = _gscache.Scene(volume, json.dumps(tables, default=_json_number))

    @classmethod
    def from_volume(cls, volume: Any, colormap: str = "bone") -> "Scene":
        """A scene chosen for ``volume`` (a ``Volume``, a numpy array of shape (nz, ny, nx), or
        a volume file's path), as ``gscache render VOLUME`` chooses it: a transfer function
        from the volume's histogram (window at its 0.5th-99.5th percentiles, opacity above
        Otsu's threshold) with colour map ``colormap`` (``bone``, ``viridis``, ``inferno``,
        ``cool-to-warm``, ``grayscale``), a camera framing it, a key light and a dim sky.
        ``scene.toml`` holds the choice as scene-file text, to save and edit. A file's path is
        read as the program reads it: a store of several channels shows them composited (up to
        six, each in its colour, as ``[[channel]]`` tables)."""
        import os

        self = cls.__new__(cls)
        if isinstance(volume, (str, os.PathLike)):
            self._inner, self.toml = _gscache.Scene.from_volume_file(os.fspath(volume), colormap)
            self._path = "volume.auto.toml"
            return self
        if not isinstance(volume, Volume):
            volume = Volume.from_array(volume)
        self._inner, self.toml = _gscache.Scene.from_volume(volume, colormap, False)
        self._path = "volume.auto.toml"
        return self

    @classmethod
    def load(cls, path: str) -> "Scene":
        """Reads a scene file (TOML), as ``gscache render`` does."""
        self = cls.__new__(cls)
        self._inner = _gscache.Scene.load(str(path))
        self._path = str(path)
        return self

    def clipped(
        self,
        box: Optional[Tuple[Sequence[float], Sequence[float]]] = None,
        planes: Sequence[Tuple[Sequence[float], Sequence[float]]] = (),
    ) -> "Scene":
        """This scene with the medium cut (replacing any clipping it had): only what lies in
        ``box`` (``(min, max)`` corners, world units) is kept, and each plane ``(point,
        normal)`` cuts away the side its normal points to. No arguments: nothing is cut. The
        renderer tracks only through the kept medium, so the image is the exact render of the
        clipped volume (docs/scene-format.md, ``[clip]``)."""
        table: dict = {}
        if box is not None:
            lo, hi = box
            table["box"] = {"min": list(lo), "max": list(hi)}
        if planes:
            table["plane"] = [{"point": list(p), "normal": list(n)} for p, n in planes]
        _finite_tables(table, "clip")
        out = Scene.__new__(Scene)
        out.__dict__.update(self.__dict__)
        out._inner = self._inner.with_clipping(json.dumps(table, default=_json_number))
        return out

    @property
    def clip(self) -> dict:
        """The clipping as the ``[clip]`` table (``{}``: nothing is cut)."""
        return json.loads(self._inner.clipping)

    width = property(lambda self: self._inner.width)
    height = property(lambda self: self._inner.height)
    spp = property(lambda self: self._inner.spp, doc="Samples per pixel the scene asks for.")
    seed = property(lambda self: self._inner.seed)
    integrator = property(lambda self: self._inner.integrator)
    max_depth = property(lambda self: self._inner.max_depth, doc="-1: unlimited.")
    exposure = property(lambda self: self._inner.exposure)
    tonemap = property(lambda self: self._inner.tonemap)
    notes = property(
        lambda self: self._inner.notes,
        doc="What the readers reported, and warnings about likely mistakes.",
    )
    render_key = property(
        lambda self: self._inner.render_key,
        doc="The key of a render with the scene's own settings (its shards share it).",
    )

    def __repr__(self) -> str:
        return repr(self._inner)


def _finite_tables(value: Any, where: str) -> None:
    """Refuses a NaN or infinite number anywhere in scene tables, naming where it is: JSON has
    no such numbers, and the parser's own complaint ("expected value at line 1 column 63")
    names no field."""
    if isinstance(value, Mapping):
        for k, v in value.items():
            _finite_tables(v, f"{where}.{k}" if where else str(k))
    elif isinstance(value, np.ndarray):
        _finite_tables(value.tolist(), where)
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _finite_tables(v, f"{where}[{i}]")
    elif isinstance(value, (float, np.floating)) and not math.isfinite(float(value)):
        raise ValueError(f"{where} is {float(value)}: expected a finite number")


def _json_number(v: Any) -> Any:
    """numpy scalars and arrays in tables (a window from ``np.percentile``, say)."""
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    raise TypeError(f"{type(v).__name__} in a scene table: expected numbers, strings, lists")


class Image(np.ndarray):
    """A rendered image: a float32 (height, width, 3) numpy array of linear radiance that also
    shows itself in Jupyter, tone-mapped as its scene says (``_repr_png_``, by the program's own
    tone map). Arithmetic gives plain arrays' results; ``np.asarray(image)`` is the bare array."""

    exposure: float = 0.0
    tonemap: str = "clip"

    @staticmethod
    def of(array: np.ndarray, exposure: float = 0.0, tonemap: str = "clip") -> "Image":
        image = np.asarray(array).view(Image)
        image.exposure, image.tonemap = float(exposure), str(tonemap)
        return image

    def __array_finalize__(self, obj) -> None:
        self.exposure = getattr(obj, "exposure", 0.0)
        self.tonemap = getattr(obj, "tonemap", "clip")

    def _repr_png_(self) -> Optional[bytes]:
        if self.ndim != 3 or self.shape[2] != 3:
            return None
        import tempfile

        with tempfile.TemporaryDirectory() as folder:
            path = pathlib.Path(folder) / "image.png"
            write_png(str(path), np.ascontiguousarray(self, dtype=np.float32), self.exposure,
                      self.tonemap)
            return path.read_bytes()


def render(
    scene: Scene,
    spp: Optional[int] = None,
    *,
    seed: Optional[int] = None,
    integrator: Optional[str] = None,
    max_depth: Optional[int] = None,
    threads: Optional[int] = None,
    progress: Optional[Progress] = None,
    features: bool = False,
) -> Any:
    """Path-traces ``scene``: float32 (height, width, 3), linear radiance, as an ``Image`` (a
    numpy array that shows itself in Jupyter). ``spp``, ``seed``,
    ``integrator`` (``"uniform"`` or ``"nee"``) and ``max_depth`` (-1: unlimited) override the
    scene's. ``progress(samples_done, samples_total)`` (or ``progress(samples_done)`` for a
    callable of one argument) is called from this thread about every 50 ms; an exception it
    raises stops the render and propagates. The GIL is released while rendering.
    The image is bit-identical to ``gscache render``'s for the same scene and settings, and
    does not depend on ``threads``.

    With ``features=True`` it returns ``(image, features)``: ``features`` is a dict of the
    feature buffers over the same samples, each camera path's first scattering event:
    ``albedo`` and ``normal`` (height, width, 3), ``depth`` and ``coverage`` (height, width).
    Where a ray met no medium the albedo is what it saw (a light, the environment) clamped to
    [0, 1] and the normal 0; depth is infinite where nothing was hit.
    They are what ``denoise`` takes as guides."""
    image, samples, interrupted, _, aovs = _gscache._render(
        scene._inner, spp, seed, integrator, max_depth, threads, progress, features
    )
    if interrupted:
        raise Interrupted(image, samples)
    image = Image.of(image, scene.exposure, scene.tonemap)
    if not features:
        return image
    albedo, normal, depth, coverage = aovs
    return image, {"albedo": albedo, "normal": normal, "depth": depth, "coverage": coverage}


_denoisers: dict = {}


def _pyoidn_library() -> Optional[str]:
    """The folder of the library the ``pyoidn`` package ships, where this interpreter has it
    installed, and ``None`` where it has not or the folder is not one to load code from.

    Loading a library runs its code, so the package is looked for only in the interpreter's own
    site-packages folders (its installed distributions' metadata, never ``sys.path``, which
    holds the script's or the current folder), and its folder is refused where it lies inside
    the current folder (unless the interpreter is installed there too: a virtual environment),
    or where it, or a folder above it, belongs to another user or is writable by others. The
    program's loader (crates/denoise) applies the same rules."""
    import importlib.metadata
    import os
    import site
    import sys

    folders = list(site.getsitepackages())
    if site.ENABLE_USER_SITE:
        folders.append(site.getusersitepackages())
    folders = [f for f in folders if os.path.isdir(f)]
    found = next(iter(importlib.metadata.distributions(name="pyoidn", path=folders)), None)
    if found is None:
        return None
    folder = os.path.realpath(str(found.locate_file(os.path.join("pyoidn", "oidn", "lib"))))
    if not os.path.isdir(folder):
        return None
    here = os.path.realpath(os.getcwd())
    inside = lambda path: os.path.commonpath([path, here]) == here
    if here != os.path.dirname(here) and inside(folder) and not inside(os.path.realpath(sys.prefix)):
        return None
    if os.name == "posix":
        me, path = os.geteuid(), folder
        while True:
            st = os.stat(path)
            sticky_folder = os.path.isdir(path) and st.st_mode & 0o1000
            if st.st_uid not in (0, me) or (st.st_mode & 0o022 and not sticky_folder):
                return None
            if path == os.path.dirname(path):
                break
            path = os.path.dirname(path)
    return folder


def denoise(
    image: np.ndarray,
    albedo: Optional[np.ndarray] = None,
    normal: Optional[np.ndarray] = None,
    *,
    quality: Optional[str] = None,
    prefilter: Optional[bool] = None,
    library: Optional[str] = None,
    threads: int = 0,
) -> np.ndarray:
    """Denoises ``image`` (float32 (height, width, 3), linear HDR radiance) with Intel Open
    Image Denoise, guided by ``albedo`` (values in [0, 1]) and ``normal`` (components in
    [-1, 1]; only beside an albedo) where given: the arrays ``render(..., features=True)``
    returns. ``quality`` is ``"fast"``, ``"balanced"`` or ``"high"`` (default); ``prefilter``
    denoises the guides first (the default, as ``gscache render --denoise``: OIDN's advice for
    clean final frames; ``False`` is one filter pass instead of three). The library is ``library`` (a
    file or folder), else the one ``GSCACHE_OIDN`` names, the system's, or the copy inside the
    ``pyoidn`` package (``pip install pyoidn``); a missing one raises ``GscacheError`` saying
    how to install it. The device is kept between calls (``threads`` 0: every core)."""
    import os

    if library is None and "GSCACHE_OIDN" not in os.environ:
        library = _pyoidn_library()
    key = (library, threads)
    if key not in _denoisers:
        _denoisers[key] = _gscache.Denoiser(library, threads)
    as_f32 = lambda a: None if a is None else np.ascontiguousarray(a, dtype=np.float32)
    return _denoisers[key].denoise(
        as_f32(image), as_f32(albedo), as_f32(normal), quality, prefilter
    )


def splat_trace(cloud: Cloud, eye: Sequence[float], target: Sequence[float], **options: Any) -> np.ndarray:
    """Ray-traces ``cloud`` with stochastic transparency (Sun et al., 2025) or a baseline:
    float32 (height, width, 3). ``options`` are ``up``, ``fov``, ``width``, ``height``, ``mode``
    (``"exact"``, ``"kbuffer"``, ``"stochastic"``, ``"stochastic-pass"``), ``spp``, ``seed``,
    ``k``, ``min_transmittance``, ``samples_per_traversal``, ``depth``, ``random``,
    ``background`` and ``threads``, as ``gscache splat trace`` takes them. The GIL is released;
    Ctrl-C raises ``Interrupted`` holding the image traced so far (each pixel the mean of the
    estimates it finished)."""
    image, done, interrupted = _gscache._splat_trace(cloud, eye, target, **options)
    if interrupted:
        raise Interrupted(image, done)
    return image


def render_partial(
    scene: Scene,
    shard: Tuple[int, int],
    spp: Optional[int] = None,
    *,
    seed: Optional[int] = None,
    integrator: Optional[str] = None,
    max_depth: Optional[int] = None,
    threads: Optional[int] = None,
    progress: Optional[Progress] = None,
) -> Partial:
    """Renders shard ``(i, n)`` (the i-th of n ranges of every pixel's samples) into a
    ``Partial``; ``Partial.merge_all`` of all n gives ``render``'s image bit for bit. The
    partial's file (``Partial.write``) is the one ``gscache render --shard`` writes, so
    program and package shards merge together."""
    part, image, samples = _gscache._render_partial(
        scene._inner, tuple(shard), spp, seed, integrator, max_depth, threads, progress
    )
    if part is None:
        # No Partial (it must hold whole sample ranges), but the image of what was rendered.
        raise Interrupted(image, samples)
    return part


class Cache:
    """The GSCache radiance cache for ``scene``: initialised from the volume, read by paths
    that stop early, trained between frames. ``config`` holds the keys of an experiment file's
    ``cache`` table (``gscache render --help`` lists them with their defaults)."""

    def __init__(self, scene: Scene, config: Optional[Mapping[str, Any]] = None):
        self._inner = _gscache.Cache(scene._inner, _config_json(config))

    @classmethod
    def load(
        cls,
        scene: Scene,
        folder: str,
        config: Optional[Mapping[str, Any]] = None,
    ) -> "Cache":
        """Levels saved by ``save`` (or ``gscache render --save-cache``)."""
        self = cls.__new__(cls)
        self._inner = _gscache.Cache.load(scene._inner, str(folder), _config_json(config))
        return self

    def render(
        self,
        frames: int = 1,
        *,
        warmup: int = 0,
        spp: int = 1,
        threads: Optional[int] = None,
        progress: Optional[Progress] = None,
    ) -> np.ndarray:
        """Renders ``warmup`` frames (trained on, not kept), then ``frames`` frames of
        ``spp`` samples, trained between them; returns their mean. Frames keep counting across
        calls. Ctrl-C raises ``Interrupted`` with the frames' image so far."""
        image, interrupted = self._inner._render(frames, warmup, spp, threads, progress)
        if interrupted:
            raise Interrupted(image, 0)
        return image

    def level_images(self) -> list:
        """Each level drawn from the scene's camera, level 0 (paths of length 1) first."""
        return self._inner.level_images()

    def save(self, folder: str) -> None:
        """Writes the levels as 3DGS PLY files ``length_N.ply``."""
        self._inner.save(str(folder))

    @property
    def costs_ms(self) -> dict:
        """Mean per kept frame: ``trace``, ``lookup`` and ``train`` milliseconds."""
        return self._inner.costs_ms

    @property
    def gaussian_count(self) -> int:
        return self._inner.gaussian_count

    @property
    def levels(self) -> int:
        return self._inner.levels

    @property
    def frames(self) -> int:
        return self._inner.frames

    def __repr__(self) -> str:
        return repr(self._inner)


def _config_json(config: Optional[Mapping[str, Any]]) -> Optional[str]:
    if config is None:
        return None
    _finite_tables(dict(config), "cache")
    return json.dumps(dict(config), default=_json_number)


class Viewer:
    """A running ``gscache view`` (``gscache.view``): ``url`` to open, ``stop()`` to end it. In
    Jupyter it shows itself as the page in an IFrame."""

    def __init__(self, inner):
        self._inner = inner

    @property
    def url(self) -> str:
        return self._inner.url

    def stop(self) -> None:
        self._inner.stop()

    def _repr_html_(self) -> str:
        import html

        u = html.escape(self.url, quote=True)
        return f'<iframe src="{u}" width="100%" height="620" style="border:0"></iframe>'

    def __repr__(self) -> str:
        return f"gscache.Viewer({self.url!r})"


def view(
    scene: "Scene",
    *,
    port: int = 0,
    bind: str = "127.0.0.1",
    output: str = "out/view",
    max_clients: int = 4,
    denoise: str = "auto",
    denoise_until: int = 0,
    scale: float = 0.5,
) -> Viewer:
    """Explores ``scene`` in the browser, as ``gscache view`` does: returns at once with a
    ``Viewer`` whose ``url`` (with its token) opens the page; in Jupyter the result displays as
    the page itself. ``port`` 0 picks a free one. It listens on 127.0.0.1 unless ``bind`` says
    otherwise. Save writes into ``output`` only. ``denoise`` ("off", "auto": on where Open
    Image Denoise loads, "on"), ``denoise_until`` (the samples a pixel from which a still view
    is shown raw; 0: denoised to the last) and ``scale`` (the rendered image against the page's
    view area in device pixels, 0.1 to 2) are the program's ``--denoise``,
    ``--denoise-until`` and ``--scale``."""
    text, path = "", ""
    if getattr(scene, "_path", None):
        path = scene._path
        text = getattr(scene, "toml", None) or pathlib.Path(path).read_text()
    return Viewer(_gscache._view(scene._inner, text, path, port, bind, output, max_clients,
                                 denoise, int(denoise_until), float(scale)))


def _movie_spec(
    frames: int,
    fps: float,
    turntable_degrees: float,
    keys: Optional[Sequence[Mapping[str, Any]]],
    spp: Optional[int],
    frame_seconds: Optional[float],
    warmup: int,
    denoise: Any,
    reference_spp: Optional[int],
    scene_spp: int,
) -> str:
    """The movie's settings as the movie crate's ``MovieSpec`` JSON."""
    if spp is not None and frame_seconds is not None:
        raise ValueError("spp and frame_seconds: give one budget per frame, not both")
    if keys is not None:
        path = {"kind": "keys", "keys": [dict(k) for k in keys]}
    else:
        path = {"kind": "turntable", "degrees": float(turntable_degrees)}
    if frame_seconds is not None:
        budget = {"seconds": float(frame_seconds)}
    else:
        budget = {"spp": int(spp if spp is not None else scene_spp)}
    # True and a dict (even an empty one: the defaults) denoise; None and False do not. (An
    # empty dict is falsy: `if denoise:` once made `denoise=True` render no denoised frame.)
    if denoise is None or denoise is False:
        denoise = None
    else:
        options = {} if denoise is True else dict(denoise)
        denoise = {"quality": "high", "guides": "none", "prefilter": True, **options}
    return json.dumps({
        "frames": int(frames), "fps": float(fps), "path": path, "budget": budget,
        "warmup": int(warmup), "denoise": denoise, "reference_spp": reference_spp,
    })


def movie(
    scene: Scene,
    folder: str,
    frames: int = 120,
    *,
    fps: float = 30.0,
    turntable_degrees: float = 360.0,
    keys: Optional[Sequence[Mapping[str, Any]]] = None,
    spp: Optional[int] = None,
    frame_seconds: Optional[float] = None,
    warmup: int = 0,
    cache: Any = None,
    denoise: Any = None,
    reference_spp: Optional[int] = None,
    video: Optional[str] = "mp4",
    resume: bool = False,
    return_frames: bool = False,
    threads: Optional[int] = None,
    progress: Optional[Progress] = None,
) -> Any:
    """``gscache movie`` from Python: ``frames`` frames along a turntable of
    ``turntable_degrees`` about the scene's up (or ``keys``: dicts of ``frame``, ``eye``,
    ``target``), each of ``spp`` samples (default the scene's) or ``frame_seconds``, into
    ``folder`` as ``frame_NNNNNN.exr`` / ``.png``, ``frames.csv`` and ``movie.mp4`` (``video``:
    ``"mp4"``, ``"webm"`` or None; needs ffmpeg). ``cache``: True or a dict of an experiment
    file's ``cache`` keys for the Gaussian cache (``warmup`` frames along the path's start train
    it first); ``denoise``: True or a dict of ``quality``, ``guides``, ``prefilter``;
    ``reference_spp``: each frame's NEE reference, for the error, flicker and JOD in the
    summary. ``resume`` goes on with the movie in the folder, bit for bit. Returns the folder,
    or ``(folder, frames)`` with ``return_frames`` (float32, (frames, height, width, 3): the
    frames as shown, denoised if denoising). Ctrl-C raises ``Interrupted`` with the frames
    finished (kept in the folder)."""
    spec = _movie_spec(frames, fps, turntable_degrees, keys, spp, frame_seconds, warmup,
                       denoise, reference_spp, scene.spp)
    cache_json = _config_json({} if cache is True else cache) if cache else None
    done, interrupted, summary = _gscache._movie(
        scene._inner, str(folder), spec, cache_json, resume, None, threads, progress
    )
    if interrupted:
        stop = Interrupted(None, 0)
        stop.args = (f"movie interrupted: {done} frames are in {folder}; resume=True goes on",)
        stop.frames = done
        raise stop
    if video is not None:
        _gscache._encode_movie(scene._inner, str(folder), spec, video, cache_json)
    if not return_frames:
        return str(folder)
    denoised = denoise is not None and denoise is not False
    return str(folder), movie_frames(folder, frames, denoised=denoised)


def movie_frames(folder: str, frames: int, *, denoised: bool = False) -> np.ndarray:
    """A movie folder's frames as one float32 array (frames, height, width, 3): the denoised
    ones with ``denoised``."""
    suffix = ".denoised.exr" if denoised else ".exr"
    root = pathlib.Path(folder)
    return np.stack([read_exr(str(root / f"frame_{f:06d}{suffix}")) for f in range(frames)])
