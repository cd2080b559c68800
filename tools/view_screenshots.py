#!/usr/bin/env python3
"""The README's screenshots of `gscache view`: the page at 1280x720 and in an 800x600 window,
in headless Chromium (Debian's `chromium` and `chromium-driver`, through Selenium).

The 1280x720 shot shows the default scene converged at 32 spp with a probe clicked on the
volume (the box, the axis triad and the scale bar drawn over the image); the 800x600 one the
narrow layout (the view on top, the controls below). Written as small JPEGs.

    python tools/view_screenshots.py --program target/release/gscache --out docs
"""

import argparse
import io
import pathlib
import shutil
import signal
import subprocess
import time

from PIL import Image
from selenium import webdriver
from selenium.webdriver import ActionChains


def shoot(program, scene, window, size, out, probe):
    proc = subprocess.Popen(
        [program, "-q", "view", scene, "--port", "0", "--width", str(size[0]),
         "--height", str(size[1]), "--spp", "32", "--output", "/tmp/gscache-view-shots"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    url = proc.stdout.readline().strip()
    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or shutil.which("chromium-browser")
    for arg in ["--headless=new", "--no-sandbox", "--disable-gpu",
                f"--window-size={window[0]},{window[1]}", "--hide-scrollbars"]:
        options.add_argument(arg)
    d = webdriver.Chrome(options=options,
                         service=webdriver.ChromeService(executable_path=shutil.which("chromedriver")))
    try:
        d.set_window_size(*window)
        d.get(url)
        end = time.time() + 120
        while time.time() < end and "32 / 32 spp" not in d.find_element("id", "stats").text:
            time.sleep(0.2)
        if probe:
            ActionChains(d).move_to_element(d.find_element("id", "view")).move_by_offset(
                -40, 20).click().perform()
            time.sleep(1)
        png = d.get_screenshot_as_png()
    finally:
        d.quit()
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)
    Image.open(io.BytesIO(png)).convert("RGB").save(out, quality=82)
    print(f"wrote {out}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--program", default="target/release/gscache")
    ap.add_argument("--scene", default="data/scenes/default.toml")
    ap.add_argument("--out", default="docs")
    args = ap.parse_args()
    out = pathlib.Path(args.out)
    shoot(args.program, args.scene, (1280, 720), (640, 480), out / "view.jpg", True)
    shoot(args.program, args.scene, (800, 600), (480, 360), out / "view_800x600.jpg", False)


if __name__ == "__main__":
    main()
