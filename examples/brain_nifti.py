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
# A transfer function from the intensity percentiles: air and background transparent, soft
# tissue faint and warm, the brightest (white matter, fat) dense and pale.

# %%
lo, mid, hi = np.percentile(data[data > 0], [30, 70, 99.5])
window = [float(lo), float(hi)]
m = float((mid - lo) / (hi - lo))
transfer = {
    "window": window,
    "density_scale": 1.5,  # extinction per mm at opacity 1
    "points": [
        {"value": 0.0, "color": [0.9, 0.6, 0.5], "opacity": 0.0},
        {"value": m, "color": [0.95, 0.7, 0.55], "opacity": 0.3},
        {"value": 1.0, "color": [1.0, 0.95, 0.9], "opacity": 1.0},
    ],
}
extent = np.array(data.shape) * spacing
camera = {
    "eye": [float(1.6 * extent.max()), float(-1.2 * extent.max()), float(0.6 * extent.max())],
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
    lights=[{"center": [150.0, 120.0, 160.0], "radius": 15.0, "radiance": [60.0, 58.0, 55.0]}],
    environment=[0.15, 0.17, 0.2],
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
