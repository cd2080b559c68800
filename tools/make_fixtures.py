#!/usr/bin/env python3
"""Writes the NRRD and NIfTI test fixtures in data/fixtures/ from the bundled raw volumes.

The files are written by independent writers (pynrrd, nibabel), so the project's readers are
tested against files they did not make. Run once; the outputs are committed:

    pip install numpy pynrrd nibabel && python3 tools/make_fixtures.py
"""
import pathlib

import nibabel as nib
import nrrd
import numpy as np

root = pathlib.Path(__file__).resolve().parent.parent
vol = root / "data" / "volumes"
out = root / "data" / "fixtures"
out.mkdir(exist_ok=True)


def load(name, dims, dtype):
    x, y, z = dims
    # x fastest on disk: a C-order [z][y][x] array; transpose to [x][y][z] for the writers,
    # which take Fortran-order (x fastest) axes.
    return np.fromfile(vol / name, dtype=dtype).reshape(z, y, x).transpose(2, 1, 0)


neghip = load("neghip_64x64x64_uint8.raw", (64, 64, 64), "<u1")
headsq = load("headsq_quarter_64x64x93_uint16.raw", (64, 64, 93), "<u2")
hydrogen = load("hydrogen_orbital_64x64x64_float32.raw", (64, 64, 64), "<f4")

# NRRD: attached gzip (u16), attached raw big-endian (as int16), detached raw header (u8).
nrrd.write(str(out / "headsq_gzip.nrrd"), headsq, {"encoding": "gzip", "spacings": [3.2, 3.2, 1.5]},
           index_order="F")
nrrd.write(str(out / "headsq_be_int16.nrrd"), headsq.astype(">i2"),
           {"encoding": "raw", "endian": "big", "space directions": np.diag([3.2, 3.2, 1.5]).tolist(),
            "space": "left-posterior-superior", "space origin": [1.0, 2.0, 3.0]},
           index_order="F")
nrrd.write(str(out / "neghip_detached.nhdr"), neghip, {"encoding": "raw"}, detached_header=True,
           index_order="F")

# NIfTI: gzip-compressed u8, uncompressed f32 with spacing, and a u8 with intensity scaling.
nib.save(nib.Nifti1Image(neghip, np.eye(4)), str(out / "neghip.nii.gz"))
h = nib.Nifti1Image(hydrogen, np.diag([0.5, 0.5, 0.5, 1.0]))
nib.save(h, str(out / "hydrogen.nii"))
img = nib.Nifti1Image(neghip, np.eye(4))
img.header.set_slope_inter(2.0, -10.0)
nib.save(img, str(out / "neghip_scaled.nii.gz"))
print("wrote", sorted(p.name for p in out.iterdir()))
