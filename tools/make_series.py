"""Makes a small time series for the time-point experiment (issue 50): the bundled neghip
volume moving along +x, two voxels a time point (`np.roll`), four time points written as
`OUT/neghip_t{k}_64x64x64_uint8.raw` (the layout in the names). Not committed: generated.

    python tools/make_series.py out/series
"""

import pathlib
import sys

import numpy as np


def main():
    out = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "out/series")
    out.mkdir(parents=True, exist_ok=True)
    repo = pathlib.Path(__file__).resolve().parent.parent
    v = np.fromfile(repo / "data/volumes/neghip_64x64x64_uint8.raw", dtype=np.uint8)
    v = v.reshape(64, 64, 64)  # z, y, x
    for k in range(4):
        np.roll(v, 2 * k, axis=2).tofile(out / f"neghip_t{k}_64x64x64_uint8.raw")
    print(f"wrote 4 time points to {out}")


if __name__ == "__main__":
    main()
