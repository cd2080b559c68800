"""The package's PEP 517 build backend: maturin's, which builds the extension module, plus the
`gscache` program, so that `pip install .` installs the program with the package (issue 33:
`gscache.distributed` runs `gscache experiment --shard` on its workers).

The program is built by cargo in the release profile, as maturin builds the extension, so the crates they
share compile once. It is copied to python/gscache/_bin/gscache (ignored by git; pyproject.toml
includes it in the wheel), and the package's console script `gscache` (gscache._program) runs
it, so it is on the environment's PATH. `GSCACHE_WHEEL_PROGRAM=0` leaves it out (a wheel of
the module alone, which needs no burn).
"""

import json
import os
import pathlib
import shutil
import subprocess

import maturin
from maturin import (  # noqa: F401  (the hooks this backend takes unchanged)
    build_sdist,
    get_requires_for_build_editable,
    get_requires_for_build_sdist,
    get_requires_for_build_wheel,
    prepare_metadata_for_build_editable,
    prepare_metadata_for_build_wheel,
)

ROOT = pathlib.Path(__file__).resolve().parents[2]
BUNDLED = ROOT / "python" / "gscache" / "_bin"


def _build_program() -> None:
    shutil.rmtree(BUNDLED, ignore_errors=True)
    if os.environ.get("GSCACHE_WHEEL_PROGRAM", "1") == "0":
        return
    # GSCACHE_WHEEL_PROFILE=dev (with MATURIN_PEP517_ARGS="--profile dev" for the module)
    # builds a test wheel from what `cargo test` and `maturin develop` already built.
    profile = os.environ.get("GSCACHE_WHEEL_PROFILE", "release")
    command = [
        "cargo", "build", "--profile", profile, "--locked", "--bin", "gscache",
        "--message-format=json-render-diagnostics",
    ]
    print("building the gscache program:", " ".join(command), flush=True)
    done = subprocess.run(command, cwd=ROOT, stdout=subprocess.PIPE, text=True, check=True)
    built = None
    for line in done.stdout.splitlines():
        message = json.loads(line)
        if message.get("reason") == "compiler-artifact" and message["target"]["name"] == "gscache":
            built = message.get("executable") or built
    if built is None:
        raise RuntimeError("cargo built no `gscache` executable: see its output above")
    BUNDLED.mkdir(parents=True)
    bundled = BUNDLED / pathlib.Path(built).name
    shutil.copy2(built, bundled)
    bundled.chmod(0o755)
    # The release profile keeps line tables for profiling (220 MB); the wheel's copy needs none
    # (16 MB stripped).
    strip = shutil.which("strip")
    if strip and os.name == "posix":
        subprocess.run([strip, str(bundled)], check=True)


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    try:
        _build_program()
        return maturin.build_wheel(wheel_directory, config_settings, metadata_directory)
    finally:
        # Not left in the source tree, where an editable install would find a stale program.
        shutil.rmtree(BUNDLED, ignore_errors=True)


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    # An editable install runs the package from python/, so the program stays there (rebuilt
    # by the next `pip install -e .`).
    _build_program()
    return maturin.build_editable(wheel_directory, config_settings, metadata_directory)
