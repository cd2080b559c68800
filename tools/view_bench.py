#!/usr/bin/env python3
"""The viewer in a real browser, timed: frames shown a second while dragging, and the time from
an edit to its first frame on screen, for plain NEE and the Gaussian cache (issue 52's table).

Headless Chromium (Debian's `chromium` and `chromium-driver`) drives `gscache view` through
Selenium's WebDriver: a drag is real pointer input (W3C actions, one move every 33 ms for
`--drag-seconds`), and frames are counted in the page, by the `load` events of the image the
page shows. The browser runs on the same cores as the renderer, as a user's would.

    python tools/view_bench.py --sizes 640x360 1280x720 --methods nee cache --repeats 3

Prints a Markdown table (medians and ranges) for BENCHMARKS.md.
"""

import argparse
import shutil
import statistics
import subprocess
import time

from selenium import webdriver
from selenium.webdriver.common.actions.action_builder import ActionBuilder
from selenium.webdriver.common.actions.pointer_input import PointerInput
from selenium.webdriver.common.actions.interaction import POINTER_MOUSE

COUNT_FRAMES = """
const img = document.getElementById('frame');
if (!window.__frames) {
  window.__frames = [];
  window.__moves = [];
  img.addEventListener('load', () => window.__frames.push(performance.now()));
  document.getElementById('view').addEventListener(
    'pointermove', (e) => { if (e.buttons) window.__moves.push(performance.now()); });
}
return performance.now();
"""

STATS = "return document.getElementById('stats').textContent;"


def browser(width, height):
    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or shutil.which("chromium-browser")
    for arg in ["--headless=new", "--no-sandbox", "--disable-gpu",
                f"--window-size={width},{height}"]:
        options.add_argument(arg)
    service = webdriver.ChromeService(executable_path=shutil.which("chromedriver"))
    return webdriver.Chrome(options=options, service=service)


def frames_since(d, t0):
    return [t for t in d.execute_script("return window.__frames;") if t >= t0]


def wait_still(d, quiet=1.0, timeout=60):
    """Waits until no frame has arrived for `quiet` seconds (the still view converged)."""
    end = time.time() + timeout
    last = None
    while time.time() < end:
        n = len(d.execute_script("return window.__frames;"))
        if n == last:
            return
        last = n
        time.sleep(quiet)
    raise TimeoutError("the view did not settle")


def drag(d, seconds, step_ms=33):
    """A left-button drag across the view, one 4-pixel move every `step_ms`."""
    view = d.find_element("id", "frame")
    mouse = PointerInput(POINTER_MOUSE, "mouse")
    actions = ActionBuilder(d, mouse=mouse, duration=step_ms)
    rect = view.rect
    x0 = int(rect["x"] + rect["width"] * 0.3)
    y0 = int(rect["y"] + rect["height"] * 0.5)
    actions.pointer_action.move_to_location(x0, y0)
    actions.pointer_action.pointer_down()
    steps = int(seconds * 1000 / step_ms)
    for i in range(steps):
        actions.pointer_action.move_to_location(x0 + 4 * ((i % 60) - 30) // 2 + 60, y0)
    actions.pointer_action.pointer_up()
    actions.perform()


def measure(url, method, drag_seconds, window):
    d = browser(*window)
    try:
        d.get(url)
        d.execute_script(COUNT_FRAMES)
        while "spp" not in d.execute_script(STATS):
            time.sleep(0.1)
        if method != "nee":
            d.execute_script(
                "const s = document.getElementById('method'); s.value = arguments[0];"
                "s.dispatchEvent(new Event('change'));", method)
        wait_still(d)
        # Edit to first frame on screen: a colour-map preset, on a converged view.
        t0 = d.execute_script(
            "const s = document.getElementById('colormap');"
            "s.selectedIndex = (s.selectedIndex + 1) % s.options.length;"
            "const t = performance.now(); s.dispatchEvent(new Event('change')); return t;")
        end = time.time() + 10
        while not frames_since(d, t0) and time.time() < end:
            time.sleep(0.005)
        edit_ms = frames_since(d, t0)[0] - t0
        wait_still(d)
        # A drag: frames shown a second over its second half (the first half includes the
        # first step's latency), and that latency.
        t0 = d.execute_script("return performance.now();")
        drag(d, drag_seconds)
        t1 = d.execute_script("return performance.now();")
        shown = frames_since(d, t0)
        moves = [t for t in d.execute_script("return window.__moves;") if t >= t0]
        mid = t0 + (t1 - t0) / 2
        late = [t for t in shown if mid <= t <= t1]
        fps = len(late) / ((t1 - mid) / 1000)
        # From the drag's first move (as the page saw it) to the first frame after it.
        after = [t for t in shown if moves and t > moves[0]]
        first_ms = after[0] - moves[0] if after else float("nan")
        return fps, first_ms, edit_ms
    finally:
        d.quit()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--program", default="target/release/gscache")
    ap.add_argument("--scene", default="data/scenes/default.toml")
    ap.add_argument("--sizes", nargs="+", default=["640x360", "1280x720"])
    ap.add_argument("--methods", nargs="+", default=["nee", "cache"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--drag-seconds", type=float, default=4.0)
    args = ap.parse_args()
    print("| view | method | fps shown while dragging | first drag move to a frame (ms) | edit to screen (ms) |")
    print("|---|---|---|---|---|")
    for size in args.sizes:
        w, h = (int(v) for v in size.split("x"))
        for method in args.methods:
            rows = []
            for _ in range(args.repeats):
                proc = subprocess.Popen(
                    [args.program, "-q", "view", args.scene, "--port", "0", "--width", str(w),
                     "--height", str(h), "--spp", "16", "--output", "/tmp/view_bench_out"],
                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                try:
                    url = proc.stdout.readline().strip()
                    rows.append(measure(url, method, args.drag_seconds, (w + 400, h + 300)))
                finally:
                    proc.terminate()
                    proc.wait(timeout=20)

            def cell(i, fmt):
                v = [r[i] for r in rows]
                return f"{fmt(statistics.median(v))} ({fmt(min(v))}-{fmt(max(v))})"

            print(f"| {size} | {method} | {cell(0, lambda x: f'{x:.1f}')} | "
                  f"{cell(1, lambda x: f'{x:.0f}')} | {cell(2, lambda x: f'{x:.0f}')} |",
                  flush=True)


if __name__ == "__main__":
    main()
