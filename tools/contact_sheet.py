"""Contact sheet of every bundled volume file rendered with no scene file (issue 33): each
through `gscache.Scene.from_volume`, as `gscache render VOLUME` renders it, 256x256 at 32 spp.
Writes docs/contact_sheet.jpg (needs Pillow for the labels and the JPEG).

    python tools/contact_sheet.py
"""

import pathlib

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
    for f in FILES:
        scene = gscache.Scene.from_volume(ROOT / f)
        text = scene.toml.replace("width = 512", f"width = {SIZE}").replace(
            "height = 512", f"height = {SIZE}"
        )
        path = ROOT / "target" / "contact.toml"
        path.write_text(text)
        image = gscache.render(gscache.Scene.load(str(path)), spp=32)
        tile = Image.fromarray(tone(image))
        ImageDraw.Draw(tile).text((6, 6), pathlib.Path(f).name, fill=(20, 20, 20))
        tiles.append(tile)
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
