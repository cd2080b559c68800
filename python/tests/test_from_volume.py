"""`Scene.from_volume`: a scene chosen for a bare volume, from a file or a numpy array, as
`gscache render VOLUME` chooses it."""

import re

import numpy as np
import pytest

import gscache


def shown_fraction(image):
    """The fraction of pixels that differ from the corner (the background) by 10%."""
    bg = image[0, 0]
    return float((np.abs(image - bg).max(-1) > 0.1 * bg.max()).mean())


def test_a_volume_file_gets_a_scene_that_shows_it(repo):
    scene = gscache.Scene.from_volume(repo / "data/fixtures/neghip.nii.gz")
    assert "[transfer]" in scene.toml and "neghip.nii.gz" in scene.toml
    image = gscache.render(scene, spp=2)
    assert image.shape == (512, 512, 3)
    # Measured: 10% of the pixels show neghip; an empty or black frame has none.
    assert shown_fraction(image) > 0.025


def test_a_numpy_array_gets_a_scene_that_shows_it():
    # A sphere of value 200 in empty space, in uint8: the threshold falls between them.
    z, y, x = np.mgrid[:40, :40, :40]
    ball = (((x - 20) ** 2 + (y - 20) ** 2 + (z - 20) ** 2) < 12**2) * np.uint8(200)
    scene = gscache.Scene.from_volume(ball.astype(np.uint8), colormap="viridis")
    # The scene file's window, whatever the writer's number format (0 or 0.0).
    window = re.search(r"(?m)^window = \[([^\]]*)\]", scene.toml)
    assert window and [float(v) for v in window.group(1).split(",")] == [0, 200], scene.toml
    image = gscache.render(scene, spp=2)
    assert shown_fraction(image) > 0.05


def test_an_unknown_colour_map_is_named():
    with pytest.raises(gscache.GscacheError, match="viridis"):
        gscache.Scene.from_volume(np.zeros((4, 4, 4), np.uint8), colormap="jet")
