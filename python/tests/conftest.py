"""Shared fixtures: the repository, the `gscache` program (built once, so renders from the
package can be compared with the program's bit for bit) and a scratch folder."""

import os
import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def repo() -> pathlib.Path:
    return REPO


@pytest.fixture(scope="session")
def program() -> str:
    """The `gscache` binary: $GSCACHE_BIN, else the one the README's `cargo test --workspace`
    builds (a no-op after it; the same command builds it otherwise). Any other cargo command
    would build the program again: the tests' dev-dependencies change the features of some of
    its dependencies, and a dev-profile build changes every crate's options.
    """
    given = os.environ.get("GSCACHE_BIN")
    if given:
        return given
    subprocess.run(
        ["cargo", "test", "--quiet", "--locked", "--workspace", "--no-run"],
        cwd=REPO,
        check=True,
    )
    return str(REPO / "target" / "debug" / "gscache")


def run_program(program: str, *args: str, env=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [program, "-q", *map(str, args)], capture_output=True, text=True, cwd=REPO, env=env
    )


def import_ome_zarr_package(name: str):
    """Imports `name`, a module of PyPI's `ome-zarr` or of `zarr`, which it installs: the test
    is skipped where it is missing, and fails instead under GSCACHE_REQUIRE_OME_ZARR=1 (CI,
    whose venv has it)."""
    import importlib

    try:
        return importlib.import_module(name)
    except ImportError:
        if os.environ.get("GSCACHE_REQUIRE_OME_ZARR") == "1":
            pytest.fail(f"needs {name} (pip install ome-zarr) (GSCACHE_REQUIRE_OME_ZARR=1)")
        pytest.skip(f"needs {name} (pip install ome-zarr)")


def small_default_scene(repo: pathlib.Path, folder: pathlib.Path, width: int, height: int) -> pathlib.Path:
    """The bundled default scene at `width` x `height`, written into `folder` (its volume path
    made absolute), so a test renders it in milliseconds."""
    text = (repo / "data/scenes/default.toml").read_text()
    text = text.replace("width = 512", f"width = {width}").replace("height = 512", f"height = {height}")
    text = text.replace('file = "../volumes/', f'file = "{repo}/data/volumes/')
    path = folder / f"default_{width}x{height}.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def client():
    """A Dask LocalCluster of 2 single-threaded worker processes (the tests that use it are
    skipped where `distributed` is not installed)."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as c:
        yield c
