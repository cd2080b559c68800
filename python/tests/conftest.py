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
    """The `gscache` binary: $GSCACHE_BIN, else built with cargo (a no-op when up to date)."""
    given = os.environ.get("GSCACHE_BIN")
    if given:
        return given
    subprocess.run(
        ["cargo", "build", "--quiet", "--locked", "--bin", "gscache"], cwd=REPO, check=True
    )
    return str(REPO / "target" / "debug" / "gscache")


def run_program(program: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [program, "-q", *map(str, args)], capture_output=True, text=True, cwd=REPO
    )
