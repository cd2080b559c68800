#!/usr/bin/env bash
# The Python package's tests: a venv in target/py-venv (kept between runs, never committed),
# the package built into it by maturin (dev profile: the workspace's optimised dependencies),
# then pytest. Run from anywhere; CI runs it after `cargo test`.
set -euo pipefail
cd "$(dirname "$0")/.."
python=${PYTHON:-python3}
venv=target/py-venv
if [ ! -x "$venv/bin/python" ]; then
    "$python" -m venv "$venv"
fi
# shellcheck disable=SC1091
. "$venv/bin/activate"
python -m pip install --quiet --disable-pip-version-check "maturin>=1.9,<2" "numpy>=1.21" \
    "pytest>=7" "distributed>=2023.1" "nibabel>=4" "selenium>=4.20" "ome-zarr>=0.10"
# Intel Open Image Denoise for the denoising tests (its wheel ships the library): only where
# asked (CI sets GSCACHE_REQUIRE_OIDN=1), since it is an 88 MB download; without it those
# tests are skipped.
if [ "${GSCACHE_REQUIRE_OIDN:-}" = 1 ]; then
    python -m pip install --quiet --disable-pip-version-check "pyoidn==2.5.1.0"
fi
# Not incremental: the caches would add gigabytes to target/ for a build that is not edited
# between runs (a clone's whole test command is held to 4 GB: README).
CARGO_INCREMENTAL=0 maturin develop --quiet
python -m pytest -q python/tests "$@"
