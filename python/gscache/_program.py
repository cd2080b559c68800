"""The `gscache` program from the package: the console script `gscache` that `pip install .`
puts on the environment's PATH, and `gscache.program()`, the path the package runs.

The wheel carries the program as gscache/_bin/gscache (built by tools/wheel's backend). An
editable install (`maturin develop`) or a wheel built with GSCACHE_WHEEL_PROGRAM=0 has none:
then $GSCACHE_BIN names one, as it does for the tests.
"""

import os
import pathlib
import subprocess
import sys
from typing import Optional

BUNDLED = pathlib.Path(__file__).resolve().parent / "_bin" / ("gscache.exe" if os.name == "nt" else "gscache")


def program() -> Optional[str]:
    """The `gscache` program this package runs: $GSCACHE_BIN where set, else the one installed
    with the package, else None."""
    given = os.environ.get("GSCACHE_BIN")
    if given:
        return given
    return str(BUNDLED) if BUNDLED.is_file() else None


def main() -> None:
    found = program()
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
