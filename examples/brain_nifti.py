# %% [markdown]
# # A brain MRI from NIfTI, rendered with and without the radiance cache
#
# The volume is `anatomical.nii`, a T1-weighted brain scan of 33 x 41 x 25 voxels at 2 mm that
# ships with nibabel (its test data), so nothing is downloaded. Run it as a script or open it
# as a notebook (jupytext reads the `# %%` cells).
#
# Set-up: `pip install . nibabel` from the repository's root.

# %%
import os
import pathlib
import time

import nibabel
import numpy as np

import gscache

out = pathlib.Path(os.environ.get("GSCACHE_EXAMPLE_OUT", "out/example"))
out.mkdir(parents=True, exist_ok=True)
size = int(os.environ.get("GSCACHE_EXAMPLE_SIZE", "256"))

# %% [markdown]
# nibabel indexes voxels as `data[x, y, z]`; gscache takes arrays of shape (nz, ny, nx) with x
# fastest in memory, which is the transpose. A transposed view is fine: its strides are read
# as they are, without a copy in Python.

# %%
# nibabel's test data folder (nibabel.testing would import pytest; the path alone does not).
data_path = os.path.join(os.path.dirname(nibabel.__file__), "tests", "data")
image = nibabel.load(os.path.join(data_path, "anatomical.nii"))
data = np.asarray(image.dataobj).astype(np.float32)
spacing = [float(z) for z in image.header.get_zooms()[:3]]
volume = gscache.Volume.from_array(data.T, spacing=spacing)
print(volume)

# %% [markdown]
# The volume is a crop of the brain's centre: tissue fills the whole box, so a transfer function
# that shows "everything above the background" shows a block. What a T1 image shows well there
# is the lateral ventricles: cerebrospinal fluid is the darkest tissue in T1. So the darkest 5%
# of voxels are opaque blue, grey matter is clear, and white matter (the brightest 40%) is a faint
# haze that places the ventricles in the brain. The thresholds are percentiles, so the same cell
# works on another T1 scan.

# %%
lo, csf, white, hi = np.percentile(data, [1, 5, 60, 99.5])


def at(v):
    """An intensity's position in the window [lo, hi]."""
    return float((v - lo) / (hi - lo))


transfer = {
    "window": [float(lo), float(hi)],
    "density_scale": 1.0,  # extinction per mm at opacity 1
    "points": [
        {"value": 0.0, "color": [0.35, 0.55, 0.95], "opacity": 1.0},
        {"value": at(csf), "color": [0.35, 0.55, 0.95], "opacity": 1.0},
        {"value": at(csf) + 0.06, "color": [0.9, 0.8, 0.7], "opacity": 0.0},
        {"value": at(white), "color": [0.95, 0.85, 0.75], "opacity": 0.0},
        {"value": 1.0, "color": [1.0, 0.95, 0.9], "opacity": 0.06},
    ],
}
# nibabel's axes here are (left, anterior, superior): look from the front, right and above.
r = float(max(np.array(data.shape) * spacing))
camera = {
    "eye": [-1.3 * r, 1.5 * r, 1.6 * r],
    "target": [0.0, 0.0, 0.0],
    "up": [0.0, 0.0, 1.0],
    "fov_y": 35.0,
    "width": size,
    "height": size,
}
scene = gscache.Scene(
    volume,
    transfer=transfer,
    camera=camera,
    lights=[{"type": "distant", "direction": [0.3, -0.4, -0.85], "irradiance": [3.0, 2.9, 2.8]}],
    environment=[0.3, 0.31, 0.34],
    render={"spp": 16, "max_depth": 32, "integrator": "nee", "seed": 1},
    output={"exposure": 0.0, "tonemap": "aces"},
)
for note in scene.notes:
    print("note:", note)

# %% [markdown]
# Plain path tracing with next-event estimation, 16 samples per pixel.

# %%
t0 = time.time()
nee = gscache.render(scene, spp=16)
print(f"nee: 16 spp in {time.time() - t0:.2f} s")
gscache.write_exr(str(out / "brain_nee.exr"), nee)
gscache.write_png(str(out / "brain_nee.png"), nee, tonemap="aces")

# %% [markdown]
# The radiance cache: 16 warm-up frames train it, then 4 frames of 1 sample each read it where
# paths stop early. The level images show what it learned for paths of length 1 and 2.

# %%
t0 = time.time()
cache = gscache.Cache(scene)
cached = cache.render(4, warmup=16, spp=1)
print(f"cache: 4 frames after 16 warm-up in {time.time() - t0:.2f} s; per frame {cache.costs_ms}")
gscache.write_exr(str(out / "brain_cache.exr"), cached)
gscache.write_png(str(out / "brain_cache.png"), cached, tonemap="aces")
for level, img in enumerate(cache.level_images(), start=1):
    gscache.write_png(str(out / f"brain_cache_length_{level}.png"), img, tonemap="aces")
cache.save(str(out / "brain_cache_levels"))
print("wrote", out)
