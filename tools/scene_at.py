"""A bundled scene at another image size, for the tools: the scene file copied with its width
and height replaced and its relative paths made absolute (so the copy renders from anywhere)."""

import pathlib
import re

import gscache

ROOT = pathlib.Path(__file__).resolve().parents[1]


def scene_at(name: str, width: int, height: int, folder: pathlib.Path) -> gscache.Scene:
    path = ROOT / "data" / "scenes" / f"{name}.toml"
    text = path.read_text()
    text = re.sub(r"(?m)^width = \d+", f"width = {width}", text)
    text = re.sub(r"(?m)^height = \d+", f"height = {height}", text)
    text = re.sub(
        r'(file|preset) = "([^"/][^"]*)"',
        lambda m: f'{m.group(1)} = "{(path.parent / m.group(2)).resolve()}"',
        text,
    )
    out = folder / f"{name}.toml"
    out.write_text(text)
    return gscache.Scene.load(str(out))
