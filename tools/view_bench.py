#!/usr/bin/env python3
"""What `gscache view` puts on screen, in a real browser, scored (issue 65).

Headless Chromium (Debian's `chromium` and `chromium-driver`) drives the viewer through
Selenium's WebDriver with real pointer input. Every frame the page shows is recorded as it is
shown (the image's `load` event), with the statistics the server sent with it (its camera, its
samples, whether it was denoised), over one scripted interaction:

    drag 3 s (a move every 33 ms, starting 8 px from the press: a press that moves 3 px or
    less is a click, which the old harness's first moves were), release, wait 5 s, change the
    transfer function (the next colour-map preset), wait 3 s.

Reported per policy (`--policies`: `today` = plain NEE, raw, as the viewer showed it before
issue 65, but at the same render size as the others; `nee-oidn`; `cache`; `cache-oidn`):
- distinct camera views shown a second over the drag (not image loads: a view shown twice,
  refined, counts once);
- the time from the release to the first full-size frame, and to the first full-size denoised
  frame;
- the time from the transfer function's edit to its first frame, to its first full-size frame
  and to its first full-size denoised frame;
- FLIP (LDR, NVIDIA's `flip-evaluator` from PyPI) of the frame on screen 1 s and 5 s after the
  release against a converged render of the released camera (`gscache render` of the scene
  the viewer's Save writes, `--reference-spp` samples), both at the page's view area in device
  pixels, the frame stretched bilinearly as the browser stretches it: a lower resolution scale
  pays for its blur.

    python tools/view_bench.py --scene data/scenes/default.toml --runs 3 --csv docs/results/viewer_on_screen.csv

Prints a Markdown table (medians of the runs, with their range) and writes the CSV rows. The
browser runs on the same cores as the renderer, as a user's would.
"""

import argparse
import base64
import csv
import io
import os
import shutil
import statistics
import subprocess
import tempfile
import time

import numpy as np
from PIL import Image
from selenium import webdriver
from selenium.webdriver.common.actions.action_builder import ActionBuilder
from selenium.webdriver.common.actions.interaction import POINTER_MOUSE
from selenium.webdriver.common.actions.pointer_input import PointerInput

# Installed before the page's own script: every binary message (a frame) is kept with the
# statistics that follow it, and the time the page's image showed it.
RECORD = """
window.__frames = [];
window.__moves = [];
window.__cameras = [];
document.addEventListener('pointermove', (e) => { if (e.buttons) window.__moves.push(performance.now()); }, true);
const NativeSocket = window.WebSocket;
window.WebSocket = class extends NativeSocket {
  send(data) {
    if (typeof data === 'string' && data.includes('"camera"')) window.__cameras.push(performance.now());
    super.send(data);
  }
  constructor(url, protocols) {
    super(url, protocols);
    this.addEventListener('message', (e) => {
      if (typeof e.data !== 'string') {
        window.__frames.push({ blob: e.data, arrived: performance.now(), shown: null, stats: null });
      } else {
        const m = JSON.parse(e.data);
        const last = window.__frames[window.__frames.length - 1];
        if (m.type === 'stats' && last && !last.stats) last.stats = m;
      }
    });
  }
};
const nativeUrl = URL.createObjectURL;
window.__urls = new Map();
URL.createObjectURL = function (blob) {
  const url = nativeUrl.call(URL, blob);
  const f = window.__frames.find((x) => x.blob === blob);
  if (f) window.__urls.set(url, f);
  return url;
};
document.addEventListener('DOMContentLoaded', () => {
  const img = document.getElementById('frame');
  img.addEventListener('load', () => {
    const f = window.__urls.get(img.src);
    if (f && f.shown === null) f.shown = performance.now();
  });
});
"""

# The frames shown, as [shown time, stats, index]; blobs read back one at a time.
SHOWN = """
return window.__frames.map((f, i) => [f.shown, f.stats, i]).filter((x) => x[0] !== null);
"""
BLOB = """
const done = arguments[arguments.length - 1];
const r = new FileReader();
r.onload = () => done(r.result.split(',')[1]);
r.readAsDataURL(window.__frames[arguments[0]].blob);
"""

POLICIES = {
    "today": ("nee", False),
    "nee-oidn": ("nee", True),
    "cache": ("cache", False),
    "cache-oidn": ("cache", True),
}


def browser(width, height):
    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or shutil.which("chromium-browser")
    for arg in ["--headless=new", "--no-sandbox", "--disable-gpu",
                f"--window-size={width},{height}"]:
        options.add_argument(arg)
    service = webdriver.ChromeService(executable_path=shutil.which("chromedriver"))
    d = webdriver.Chrome(options=options, service=service)
    d.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": RECORD})
    return d


def wait_for(predicate, timeout=60):
    end = time.time() + timeout
    while time.time() < end:
        if predicate():
            return
        time.sleep(0.05)
    raise TimeoutError("the page did not get there")


def drag(d, seconds, step_ms=33):
    """A left-button drag across the view: the first move 8 px from the press, then one
    4-pixel move every `step_ms`, one way (every camera new)."""
    view = d.find_element("id", "frame")
    mouse = PointerInput(POINTER_MOUSE, "mouse")
    actions = ActionBuilder(d, mouse=mouse, duration=step_ms)
    rect = view.rect
    x0 = int(rect["x"] + rect["width"] * 0.1)
    y0 = int(rect["y"] + rect["height"] * 0.5)
    actions.pointer_action.move_to_location(x0, y0)
    actions.pointer_action.pointer_down()
    steps = int(seconds * 1000 / step_ms)
    for i in range(steps):
        actions.pointer_action.move_to_location(x0 + 8 + 4 * i, y0)
    actions.pointer_action.pointer_up()
    actions.perform()


def flip_ldr(reference, test):
    import flip_evaluator

    ref = np.asarray(reference, dtype=np.float32) / 255.0
    img = np.asarray(test.resize(reference.size, Image.BILINEAR), dtype=np.float32) / 255.0
    _, mean, _ = flip_evaluator.evaluate(ref, img, "LDR")
    return float(mean)


def run_once(program, scene, policy, window, out, wait_s, scale):
    method, denoise = POLICIES[policy]
    args = [program, "-q", "view", scene, "--port", "0", "--spp", "64", "--output", out]
    if scale is not None:
        args += ["--scale", str(scale)]
    args += ["--denoise", "on" if denoise else "off"]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    d = None
    try:
        url = proc.stdout.readline().strip()
        d = browser(*window)
        d.get(url)
        wait_for(lambda: "spp" in d.find_element("id", "stats").text)
        if method != "nee":
            d.execute_script(
                "const s = document.getElementById('method'); s.value = arguments[0];"
                "s.dispatchEvent(new Event('change'));", method)
        time.sleep(3.0)  # the view refines (and the cache trains) before the drag
        t0 = d.execute_script("return performance.now();")
        drag(d, 3.0)
        released = d.execute_script("return performance.now();")
        time.sleep(wait_s)
        d.find_element("id", "save").click()
        wait_for(lambda: "saved" in d.find_element("id", "error").text)
        # The transfer function changed (the next colour-map preset), then 3 s.
        edited = d.execute_script(
            "const s = document.getElementById('colormap');"
            "s.selectedIndex = (s.selectedIndex + 1) % s.options.length;"
            "const t = performance.now(); s.dispatchEvent(new Event('change')); return t;")
        time.sleep(3.0)
        shown = d.execute_script(SHOWN)
        view_w = max(s["view_width"] for _, s, _ in shown if s)
        during = [(t, s) for t, s, _ in shown if s and t0 <= t <= released and s["moving"]]
        # A view counts when it differs from the one shown before it.
        views = [s for (_, s), (_, prev) in zip(during, [(None, None)] + during)
                 if prev is None or s["eye"] != prev["eye"]]
        drag_s = (released - t0) / 1000
        after = [(t, s, i) for t, s, i in shown
                 if s and released < t < edited and not s["moving"]]
        # Frames made after the edit: their statistics count one edit more than the last frame
        # shown before it (a frame already on its way arrives after the edit too).
        before_edit = [s for t, s, _ in shown if s and t <= edited][-1]["edits"]
        edit_frames = [(t, s) for t, s, _ in shown if s and t > edited and s["edits"] > before_edit]
        edit_full = [t for t, s in edit_frames if s["width"] == view_w]
        edit_clean = [t for t, s in edit_frames if s["width"] == view_w and s["denoised"]]
        full = [t for t, s, _ in after if s["width"] == view_w]
        clean = [t for t, s, _ in after if s["width"] == view_w and s["denoised"]]

        def on_screen_at(seconds):
            at = released + 1000 * seconds
            before = [(t, i) for t, s, i in shown if t <= at]
            index = before[-1][1]
            data = d.execute_async_script(BLOB, index)
            return Image.open(io.BytesIO(base64.b64decode(data))).convert("RGB")

        frames = {s: on_screen_at(s) for s in (1.0, wait_s)}
        area = d.execute_script(
            "const r = document.getElementById('view').getBoundingClientRect();"
            "const k = window.devicePixelRatio || 1;"
            "return [Math.round(r.width * k), Math.round(r.height * k)];")
        final = next(s for t, s, _ in reversed(shown) if s)
        rendered = [s["sequence"] for t, s in during]
        moves = [t for t in d.execute_script("return window.__moves;") if t0 <= t <= released]
        cameras = [t for t in d.execute_script("return window.__cameras;") if t0 <= t <= released]
        if os.environ.get("VIEW_BENCH_VERBOSE") and during:
            keys = ["trace_ms", "denoise_ms", "encode_ms"]
            means = {k: statistics.mean(s[k] for _, s in during) for k in keys}
            print(f"  drag: {during[-1][1]['width']}x{during[-1][1]['height']} " +
                  " ".join(f"{k} {v:.1f}" for k, v in means.items()))
        if os.environ.get("VIEW_BENCH_VERBOSE"):
            for t, s, _ in after[:6]:
                print(f"  +{t - released:.0f} ms: {s['width']}x{s['height']} spp {s['spp']} "
                      f"denoised {s['denoised']} trace {s['trace_ms']:.0f} ms "
                      f"denoise {s['denoise_ms']:.0f} ms encode {s['encode_ms']:.0f} ms")
        return {
            "frames_rendered_per_s": (max(rendered) - min(rendered) + 1) / drag_s if rendered else 0,
            "pointer_moves_per_s": len(moves) / drag_s,
            "edit_to_frame_ms": (edit_frames[0][0] - edited) if edit_frames else float("nan"),
            "edit_to_full_ms": (edit_full[0] - edited) if edit_full else float("nan"),
            "edit_to_denoised_ms": (edit_clean[0] - edited) if edit_clean else float("nan"),
            "cameras_sent_per_s": len(cameras) / drag_s,
            "distinct_views_per_s": len(views) / drag_s,
            "frames_shown_per_s": len(during) / drag_s,
            "release_to_full_ms": (full[0] - released) if full else float("nan"),
            "release_to_denoised_ms": (clean[0] - released) if clean else float("nan"),
            "frames": frames,
            "view": (final["view_width"], final["view_height"]),
            # The page's view area in device pixels: the frames are scored there, stretched
            # as the browser stretches them, so a lower resolution scale pays for its blur.
            "area": tuple(area),
        }
    finally:
        if d is not None:
            d.quit()
        proc.terminate()
        proc.wait(timeout=20)


REFERENCES = {}


def reference(program, out, size, spp):
    """A converged render of the view Save wrote (at the view's size); the same script gives
    every policy the same camera, so each camera is rendered once."""
    saved = os.path.join(out, sorted(f for f in os.listdir(out) if f.endswith(".toml"))[-1])
    with open(saved) as f:
        text = f.read()
    camera = text[text.index("[camera]"):].split("\n[", 1)[0]
    key = (camera, size, spp)
    if key not in REFERENCES:
        path = os.path.join(tempfile.mkdtemp(prefix="view_bench_ref_"), "reference")
        subprocess.run([program, "-q", "render", saved, "--width", str(size[0]),
                        "--height", str(size[1]), "--spp", str(spp), "-o", path + ".exr"],
                       check=True)
        REFERENCES[key] = Image.open(path + ".png").convert("RGB")
    return REFERENCES[key]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--program", default="target/release/gscache")
    ap.add_argument("--scene", default="data/scenes/default.toml")
    ap.add_argument("--policies", nargs="+", default=list(POLICIES))
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--window", default="1280x720")
    ap.add_argument("--wait", type=float, default=5.0)
    ap.add_argument("--reference-spp", type=int, default=512)
    ap.add_argument("--default-policy", default="nee-oidn")
    ap.add_argument("--scale", type=float, help="the viewer's --scale (its default if not given)")
    ap.add_argument("--csv")
    args = ap.parse_args()
    window = tuple(int(v) for v in args.window.split("x"))
    name = os.path.splitext(os.path.basename(args.scene))[0]
    rows = []
    today_at_5 = []
    print("| scene | policy | pointer moves/s | cameras sent/s | distinct views/s dragging "
          "| frames shown/s | frames rendered/s | release to full size (ms) "
          "| release to denoised (ms) | FLIP at 1 s | FLIP at 5 s | edit to a frame (ms) "
          "| edit to full size (ms) | edit to denoised (ms) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for policy in args.policies:
        runs = []
        for _ in range(args.runs):
            out = tempfile.mkdtemp(prefix="view_bench_")
            r = run_once(args.program, args.scene, policy, window, out, args.wait, args.scale)
            ref = reference(args.program, out, r["area"], args.reference_spp)
            r["flip_1"] = flip_ldr(ref, r["frames"][1.0])
            r["flip_5"] = flip_ldr(ref, r["frames"][args.wait])
            runs.append(r)
            shutil.rmtree(out, ignore_errors=True)

        def med(key):
            v = [r[key] for r in runs]
            return statistics.median(v), min(v), max(v)

        def cell(key, fmt):
            m, lo, hi = med(key)
            return f"{fmt(m)} ({fmt(lo)}-{fmt(hi)})"

        if policy == "today":
            today_at_5 = [r["flip_5"] for r in runs]
        print(f"| {name} | {policy} | {cell('pointer_moves_per_s', lambda x: f'{x:.1f}')} | "
              f"{cell('cameras_sent_per_s', lambda x: f'{x:.1f}')} | "
              f"{cell('distinct_views_per_s', lambda x: f'{x:.1f}')} | "
              f"{cell('frames_shown_per_s', lambda x: f'{x:.1f}')} | "
              f"{cell('frames_rendered_per_s', lambda x: f'{x:.1f}')} | "
              f"{cell('release_to_full_ms', lambda x: f'{x:.0f}')} | "
              f"{cell('release_to_denoised_ms', lambda x: f'{x:.0f}')} | "
              f"{cell('flip_1', lambda x: f'{x:.4f}')} | {cell('flip_5', lambda x: f'{x:.4f}')} | "
              f"{cell('edit_to_frame_ms', lambda x: f'{x:.0f}')} | "
              f"{cell('edit_to_full_ms', lambda x: f'{x:.0f}')} | "
              f"{cell('edit_to_denoised_ms', lambda x: f'{x:.0f}')} |",
              flush=True)
        rows.append({
            "scene": name, "view": f"{runs[0]['view'][0]}x{runs[0]['view'][1]}",
            "policy": policy, "default": int(policy == args.default_policy),
            "scale": args.scale if args.scale is not None else "default",
            "distinct_views_per_s": round(med("distinct_views_per_s")[0], 2),
            "frames_shown_per_s": round(med("frames_shown_per_s")[0], 2),
            "release_to_full_ms": round(med("release_to_full_ms")[0], 1),
            "release_to_denoised_ms": round(med("release_to_denoised_ms")[0], 1),
            "flip_at_1s": round(med("flip_1")[0], 5),
            "flip_at_5s": round(med("flip_5")[0], 5),
            "flip_today_at_5s": round(statistics.median(today_at_5), 5) if today_at_5 else "",
            "edit_to_frame_ms": round(med("edit_to_frame_ms")[0], 1),
            "edit_to_denoised_ms": round(med("edit_to_denoised_ms")[0], 1),
            "runs": len(runs),
        })
    if args.csv:
        new = not os.path.exists(args.csv)
        with open(args.csv, "a", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            if new:
                w.writeheader()
            w.writerows(rows)


if __name__ == "__main__":
    main()
