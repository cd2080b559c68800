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
    # Issue 48, item 12: the extension module ships stripped, as the program does.
    if sys.platform.startswith("linux"):
        [module] = list((site / "gscache").glob("_gscache*.so"))
        assert ".symtab" not in _elf_sections(module), module
        assert ".symtab" not in _elf_sections(site / "gscache" / "_bin" / "gscache")


def _elf_sections(path):
    """The section names of a 64-bit little-endian ELF file (a stripped one has no .symtab)."""
    import struct

    data = pathlib.Path(path).read_bytes()
    assert data[:4] == b"\x7fELF" and data[4] == 2 and data[5] == 1, path
    shoff, = struct.unpack_from("<Q", data, 0x28)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", data, 0x3A)
    headers = [struct.unpack_from("<IIQQQQ", data, shoff + i * shentsize) for i in range(shnum)]
    names_at = headers[shstrndx][4]
    return {data[names_at + h[0]:data.index(b"\0", names_at + h[0])].decode() for h in headers}


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


def _run_script(env, cwd):
    return subprocess.run(
        [sys.executable, "-c", "from gscache._program import main; main()", "--version"],
        capture_output=True, text=True, env=env, cwd=cwd, timeout=60,
    )


def test_gscache_bin_naming_the_console_script_is_refused_not_run_forever(tmp_path):
    """Issue 48, item 9: GSCACHE_BIN=$(which gscache) made the console script exec itself
    forever (a time-out here). Now it is refused with a message, as is a bare name that is not
    on PATH (it gave a traceback)."""
    script = tmp_path / "gscache"
    script.write_text(
        f"#!{sys.executable}\nimport sys\nfrom gscache._program import main\nsys.exit(main())\n"
    )
    script.chmod(0o755)
    for given, said in [
        (str(script), "would run itself"),
        ("gscache-no-such-program", "no program of that name on PATH"),
        (str(tmp_path), "not an executable file"),
    ]:
        env = dict(os.environ, GSCACHE_BIN=given)
        done = _run_script(env, tmp_path)
        assert done.returncode == 1, (given, done.stderr)
        assert said in done.stderr and "Traceback" not in done.stderr, (given, done.stderr)


def test_gscache_bin_may_be_a_bare_name_on_path(program, tmp_path):
    env = dict(os.environ, GSCACHE_BIN=os.path.basename(program))
    env["PATH"] = os.path.dirname(os.path.abspath(program)) + os.pathsep + env.get("PATH", "")
    done = _run_script(env, tmp_path)
    assert done.returncode == 0 and done.stdout.strip() == f"gscache {gscache.__version__}", done.stderr
