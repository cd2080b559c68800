"""The wheel installs the `gscache` program (issue 33: after `pip install .` the Dask experiment
path found no program). Builds a wheel through the package's own build backend, in the dev
profile so that it reuses what `cargo test` and `maturin develop` built, installs it into a
scratch folder and runs the console script. Slow on a cold tree (it builds the program), so it
runs where GSCACHE_TEST_WHEEL=1 (CI sets it) and is reported as skipped elsewhere."""

import os
import pathlib
import subprocess
import sys

import pytest

import gscache

needs_wheel = pytest.mark.skipif(
    os.environ.get("GSCACHE_TEST_WHEEL") != "1",
    reason="builds a wheel (minutes on a cold tree): set GSCACHE_TEST_WHEEL=1",
)


@needs_wheel
def test_the_wheel_installs_the_program(repo, tmp_path):
    env = dict(os.environ, GSCACHE_WHEEL_PROFILE="dev", MATURIN_PEP517_ARGS="--profile dev")
    env.pop("GSCACHE_BIN", None)
    wheels = tmp_path / "wheels"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(repo), "--no-deps", "--no-build-isolation",
         "--quiet", "-w", str(wheels)],
        check=True, env=env,
    )
    [wheel] = list(wheels.glob("gscache-*.whl"))
    site = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target", str(site), str(wheel)],
        check=True,
    )
    # The build left nothing in the source tree for an editable install to find.
    assert not (repo / "python" / "gscache" / "_bin").exists()
    env = dict(env, PYTHONPATH=str(site))
    script = site / "bin" / "gscache"
    version = subprocess.run([str(script), "--version"], capture_output=True, text=True, env=env)
    assert version.returncode == 0, version.stderr
    assert version.stdout.strip() == f"gscache {gscache.__version__}"
    where = subprocess.run(
        [sys.executable, "-c", "import gscache; print(gscache.program())"],
        capture_output=True, text=True, env=env, cwd=tmp_path,
    )
    assert where.stdout.strip() == str(site / "gscache" / "_bin" / "gscache"), where.stderr


def test_without_a_program_the_script_says_how_to_get_one(tmp_path):
    """An editable install (these tests' own) has no bundled program: with no GSCACHE_BIN either,
    the console script exits with a message naming the two fixes, not a traceback."""
    if (pathlib.Path(gscache.__file__).parent / "_bin").exists():
        pytest.skip("this install carries a program")
    env = {k: v for k, v in os.environ.items() if k != "GSCACHE_BIN"}
    done = subprocess.run(
        [sys.executable, "-c", "from gscache._program import main; main()", "--version"],
        capture_output=True, text=True, env=env, cwd=tmp_path,
    )
    assert done.returncode == 1
    assert "no gscache program" in done.stderr and "GSCACHE_BIN" in done.stderr
    assert "Traceback" not in done.stderr


def test_the_script_runs_the_program_named_by_gscache_bin(program, tmp_path):
    env = dict(os.environ, GSCACHE_BIN=program)
    done = subprocess.run(
        [sys.executable, "-c", "from gscache._program import main; main()", "--version"],
        capture_output=True, text=True, env=env, cwd=tmp_path,
    )
    assert done.returncode == 0 and done.stdout.strip() == f"gscache {gscache.__version__}", done.stderr
