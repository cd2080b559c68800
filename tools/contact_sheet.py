"""Contact sheet of everything bundled (issue 33), 256x256 tiles at 32 spp:
- every bundled volume file rendered with no scene file, through `gscache.Scene.from_volume`,
  as `gscache render VOLUME` renders it;
- the worked example (examples/brain_nifti.py: nibabel's T1 brain through Python, no TOML);
- every bundled scene file (data/scenes; those whose volume lives in ../shared when it is there).
Writes docs/contact_sheet.jpg (needs Pillow for the labels and the JPEG, nibabel for the example).

    python tools/contact_sheet.py
"""

import os
import pathlib
import re
import subprocess
import sys

import numpy as np
from PIL import Image, ImageDraw

import gscache

ROOT = pathlib.Path(__file__).resolve().parents[1]
FILES = [
    "data/fixtures/neghip.nii.gz",
    "data/fixtures/hydrogen.nii",
    "data/fixtures/headsq_gzip.nrrd",
    "data/fixtures/headsq_be_int16.nrrd",
    "data/fixtures/neghip_detached.nhdr",
    "data/volumes/original/ironProt.vtk",
    "data/volumes/original/hydrogen.vti",
    "data/volumes/ironProt_68x68x68_uint8.raw",
]
SCENES = ["default", "hydrogen", "headsq", "ironprot", "one_light", "chest_ct", "embryo"]
SIZE = 256


def tone(image):
    """ACES-like curve and sRGB, as the program's PNGs (exposure 0)."""
    x = image
    x = (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)
    x = np.clip(x, 0, 1)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (np.clip(x, 0, 1) * 255 + 0.5).astype(np.uint8)


def main():
    tiles = []

    def add(image, label):
        tile = Image.fromarray(tone(image))
        ImageDraw.Draw(tile).text((6, 6), label, fill=(20, 20, 20))
        tiles.append(tile)

    scratch = ROOT / "target" / "contact"
    scratch.mkdir(parents=True, exist_ok=True)
    for f in FILES:
        scene = gscache.Scene.from_volume(ROOT / f)
        text = scene.toml.replace("width = 512", f"width = {SIZE}").replace(
            "height = 512", f"height = {SIZE}"
        )
        path = scratch / "volume.toml"
        path.write_text(text)
        add(gscache.render(gscache.Scene.load(str(path)), spp=32), pathlib.Path(f).name)

    env = dict(os.environ, GSCACHE_EXAMPLE_OUT=str(scratch), GSCACHE_EXAMPLE_SIZE=str(SIZE))
    subprocess.run([sys.executable, str(ROOT / "examples/brain_nifti.py")], env=env, check=True)
    add(gscache.read_exr(str(scratch / "brain_nee.exr")), "examples/brain_nifti.py")

    for name in SCENES:
        source = ROOT / "data" / "scenes" / f"{name}.toml"
        text = source.read_text()
        # Relative paths are the scene folder's: make them absolute for the copy in target/.
        text = re.sub(r'"(\.\./[^"]*)"', lambda m: f'"{(source.parent / m.group(1)).resolve()}"', text)
        text = re.sub(r"(?m)^width = \d+", f"width = {SIZE}", text)
        text = re.sub(r"(?m)^height = \d+", f"height = {SIZE}", text)
        path = scratch / f"{name}.toml"
        path.write_text(text)
        try:
            scene = gscache.Scene.load(str(path))
        except gscache.GscacheError as e:
            if "shared" not in str(e):  # only a volume that lives in ../shared may be absent
                raise
            print(f"skipped scene {name}: {e}".splitlines()[0])
            continue
        add(gscache.render(scene, spp=32), f"data/scenes/{name}.toml")
    cols = 4
    rows = (len(tiles) + cols - 1) // cols
    sheet = Image.new("RGB", (cols * SIZE, rows * SIZE), "white")
    for i, t in enumerate(tiles):
        sheet.paste(t, ((i % cols) * SIZE, (i // cols) * SIZE))
    out = ROOT / "docs" / "contact_sheet.jpg"
    sheet.save(out, quality=85)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
