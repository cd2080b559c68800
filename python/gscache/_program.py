"""The `gscache` program from the package: the console script `gscache` that `pip install .`
puts on the environment's PATH, and `gscache.program()`, the path the package runs.

The wheel carries the program as gscache/_bin/gscache (built by tools/wheel's backend). An
editable install (`maturin develop`) or a wheel built with GSCACHE_WHEEL_PROGRAM=0 has none:
then $GSCACHE_BIN names one, as it does for the tests.
"""

import os
import pathlib
import shutil
import subprocess
import sys
from typing import Optional

BUNDLED = pathlib.Path(__file__).resolve().parent / "_bin" / ("gscache.exe" if os.name == "nt" else "gscache")


class ProgramError(RuntimeError):
    """$GSCACHE_BIN names no program this package can run."""


def _is_this_script(path: str) -> bool:
    """Whether `path` is a console script that runs this module (the `gscache` script itself, or
    another install's): executing it would run this function again, forever."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return False
    return head.startswith(b"#!") and b"gscache._program" in head


def program() -> Optional[str]:
    """The `gscache` program this package runs: $GSCACHE_BIN where set (a path, or a bare name
    looked up on PATH), else the one installed with the package, else None. Raises
    `ProgramError` where $GSCACHE_BIN names nothing runnable, or the console script itself."""
    given = os.environ.get("GSCACHE_BIN")
    if not given:
        return str(BUNDLED) if BUNDLED.is_file() else None
    found = given if os.sep in given or (os.altsep and os.altsep in given) else shutil.which(given)
    if found is None:
        raise ProgramError(f"GSCACHE_BIN={given}: no program of that name on PATH (expected the "
                           "path of the gscache program, e.g. target/release/gscache)")
    if not (os.path.isfile(found) and os.access(found, os.X_OK)):
        raise ProgramError(f"GSCACHE_BIN={given}: {found} is not an executable file (expected the "
                           "path of the gscache program, e.g. target/release/gscache)")
    if _is_this_script(found):
        raise ProgramError(f"GSCACHE_BIN={given}: {found} is this package's console script, which "
                           "would run itself forever; name the gscache program itself (e.g. "
                           "target/release/gscache), or unset GSCACHE_BIN to use the bundled one")
    return found


def main() -> None:
    try:
        found = program()
    except ProgramError as e:
        sys.exit(f"gscache: {e}")
    if found is None:
        sys.exit(
            "gscache: this install of the package has no gscache program (an editable install, "
            "or a wheel built with GSCACHE_WHEEL_PROGRAM=0). Install with `pip install .`, or "
            "build it with `cargo build --release` and set GSCACHE_BIN to target/release/gscache."
        )
    args = [found, *sys.argv[1:]]
    if os.name == "posix":
        os.execv(found, args)  # the program replaces this process: signals and exit codes are its own
    sys.exit(subprocess.call(args))
