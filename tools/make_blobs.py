#!/usr/bin/env python3
"""Writes data/volumes/blobs_48x48x48_uint8.raw: the blob scene (data/scenes/blobs.toml).

Three soft Gaussian blobs of different peak values in an empty 48^3 grid, which the scene's
transfer function colours red, green and blue: a synthetic volume whose colour channels differ
from blob to blob, so a renderer's (or a cache's) brightness error can be read per channel
(issue 53: "raw bias below 0.3% on every bundled volume and the blob scene"). Deterministic;
run once, the output is committed:

    pip install numpy && python3 tools/make_blobs.py
"""
import pathlib

import numpy as np

N = 48
# (centre in voxels, radius in voxels, value 0-255): red (low values), green, blue (high). Each
# blob is a soft ball (a logistic edge one voxel wide) whose core is denser towards its centre,
# so its rim passes through the lower blobs' values only in a thin shell.
BLOBS = [((13.0, 22.0, 24.0), 9.0, 80), ((34.0, 17.0, 21.0), 8.0, 160), ((26.0, 32.0, 29.0), 9.5, 240)]

z, y, x = np.meshgrid(np.arange(N), np.arange(N), np.arange(N), indexing="ij")
value = np.zeros((N, N, N))
for (cx, cy, cz), sigma, peak in BLOBS:  # sigma: the radius
    r2 = (x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2
    r = np.sqrt(r2)
    edge = 1.0 / (1.0 + np.exp((r - sigma) / 1.0))
    core = 1.0 - 0.15 * (r / sigma) ** 2
    value = np.maximum(value, peak * edge * np.clip(core, 0.85, 1.0))
out = pathlib.Path(__file__).resolve().parent.parent / "data" / "volumes" / f"blobs_{N}x{N}x{N}_uint8.raw"
# C order [z][y][x]: x fastest on disk, as the loader reads raw files.
np.round(value).astype("<u1").tofile(out)
print(f"wrote {out} ({out.stat().st_size} bytes)")
