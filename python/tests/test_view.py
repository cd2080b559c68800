"""`gscache view` in a real browser: headless Chromium driven through Selenium's WebDriver
(Debian's `chromium` and `chromium-driver`; .ci/run installs them). Skipped where either is
missing, unless GSCACHE_REQUIRE_BROWSER=1 (CI), which makes that a failure.

The page loads and shows a rendered frame; a drag on the view, a colour-map preset and a light
each change the image; the split view shows NEE beside the Gaussian cache; a bad value in a
field shows the server's error and the view keeps rendering; Ctrl-C stops the program
cleanly."""

import os
import shutil
import signal
import subprocess
import time

import pytest


def _require(what):
    if os.environ.get("GSCACHE_REQUIRE_BROWSER") == "1":
        pytest.fail(f"{what} (GSCACHE_REQUIRE_BROWSER=1)")
    pytest.skip(what)


@pytest.fixture
def browser():
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if not (chromium and driver):
        _require("needs Debian's chromium and chromium-driver")
    try:
        from selenium import webdriver
    except ImportError:
        _require("needs selenium (pip install selenium)")
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for arg in ["--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1100,600"]:
        options.add_argument(arg)
    d = webdriver.Chrome(options=options, service=webdriver.ChromeService(executable_path=driver))
    yield d
    d.quit()


@pytest.fixture
def viewer(program, repo, tmp_path):
    proc = subprocess.Popen(
        [program, "-q", "view", str(repo / "data/scenes/default.toml"), "--port", "0",
         "--width", "96", "--height", "54", "--output", str(tmp_path / "out"),
         # The view renders at the page's size times this: about the 96x54 of old, so that
         # each edit settles as quickly.
         "--scale", "0.1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    url = proc.stdout.readline().strip()
    assert url.startswith("http://127.0.0.1:") and "token=" in url, proc.stderr.read()
    yield url
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=20) == 0, proc.stderr.read()


# The shown frame, read back through a canvas: 16x9 grey levels (the image is a blob of the
# page's own origin, so the canvas may read it).
FRAME = """
const img = document.getElementById('frame');
if (!img.naturalWidth || !img.complete) return null;
const c = document.createElement('canvas'); c.width = 16; c.height = 9;
const g = c.getContext('2d'); g.drawImage(img, 0, 0, 16, 9);
const d = g.getImageData(0, 0, 16, 9).data, out = [];
for (let i = 0; i < d.length; i += 4) out.push((d[i] + d[i + 1] + d[i + 2]) / 3);
return out;
"""


def wait(predicate, what, timeout=60):
    end = time.time() + timeout
    while time.time() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.1)
    pytest.fail(f"timed out waiting for {what}")


def settled(d):
    """The frame once the view has refined to its samples per pixel."""
    def done():
        stats = d.find_element("id", "stats").text
        if "/" not in stats or "(moving)" in stats:
            return None
        spp, target = stats.split("\n")[1].split(" spp")[0].split(" / ")
        return d.execute_script(FRAME) if int(spp) >= int(target) else None
    return wait(done, "the view to settle")


def differ(a, b):
    return sum(abs(x - y) for x, y in zip(a, b)) / len(a)


def test_the_page_renders_and_answers_edits(viewer, browser):
    from selenium.webdriver import ActionChains
    from selenium.webdriver.support.ui import Select

    d = browser
    d.get(viewer)
    first = settled(d)
    spread = max(first) - min(first)
    assert spread > 20, f"a blank frame: {first}"
    # Issue 67, item 9: the page loads without an error in the console (a refused
    # /favicon.ico was its only one).
    errors = [e for e in d.get_log("browser") if e["level"] == "SEVERE"]
    assert not errors, errors

    # A drag orbits the camera.
    ActionChains(d).move_to_element(d.find_element("id", "view")).click_and_hold().move_by_offset(
        150, 40).release().perform()
    wait(lambda: differ(settled(d), first) > 3, "the drag to change the image")
    dragged = settled(d)

    # A colour-map preset.
    Select(d.find_element("id", "colormap")).select_by_value("inferno")
    wait(lambda: differ(settled(d), dragged) > 3, "the preset to change the image")
    coloured = settled(d)

    # A light moved to the other side.
    slider = d.find_element("css selector", "#lights input[data-k=az]")
    d.execute_script("arguments[0].value = -arguments[0].value + 90;"
                     "arguments[0].dispatchEvent(new Event('input', {bubbles: true}));", slider)
    wait(lambda: differ(settled(d), coloured) > 1, "the light to change the image")

    # The split view: NEE and the Gaussian cache side by side, at equal time.
    Select(d.find_element("id", "method")).select_by_value("cache")
    d.find_element("id", "split").click()
    wait(lambda: "split: left NEE" in d.find_element("id", "stats").text, "the split view")
    halves = settled(d)
    assert max(halves) - min(halves) > 20, f"a blank split view: {halves}"
    d.find_element("id", "split").click()
    Select(d.find_element("id", "method")).select_by_value("nee")

    # A bad value: the window's low end above its high end.
    low = d.find_element("id", "window-lo")
    d.execute_script("arguments[0].value = 1000;"
                     "arguments[0].dispatchEvent(new Event('change'));", low)
    wait(lambda: "window" in d.find_element("id", "error").text, "the error to show")
    # The view still renders: a camera edit goes through.
    before = settled(d)
    ActionChains(d).move_to_element(d.find_element("id", "view")).click_and_hold().move_by_offset(
        -200, 0).release().perform()
    wait(lambda: differ(settled(d), before) > 3, "a frame after the error")


def test_the_view_renders_at_the_window_size(program, repo, tmp_path, browser):
    """Issue 65: the image is rendered at the page's view area in device pixels times the
    resolution scale, not the scene's size stretched; resizing the window, and choosing another
    scale on the page, change the rendered image's natural size to follow."""
    from selenium.webdriver.support.ui import Select

    proc = subprocess.Popen(
        [program, "-q", "view", str(repo / "data/scenes/default.toml"), "--port", "0",
         "--spp", "2", "--scale", "0.25", "--output", str(tmp_path / "out")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        url = proc.stdout.readline().strip()
        d = browser
        d.get(url)

        def expected(scale):
            return d.execute_script(
                "const r = document.getElementById('view').getBoundingClientRect();"
                "const k = (window.devicePixelRatio || 1) * arguments[0];"
                "return [Math.round(r.width * k), Math.round(r.height * k)];", scale)

        def natural():
            return d.execute_script(
                "const i = document.getElementById('frame');"
                "return [i.naturalWidth, i.naturalHeight];")

        want = expected(0.25)
        wait(lambda: natural() == want, f"a frame of {want} (the scene is 512x512)")
        d.set_window_size(800, 700)
        wait(lambda: expected(0.25) != want, "the view area to change")
        resized = expected(0.25)
        wait(lambda: natural() == resized, f"a frame of {resized} after the resize")
        Select(d.find_element("id", "scale")).select_by_value("0.5")
        half = expected(0.5)
        wait(lambda: natural() == half, f"a frame of {half} at scale 0.5")
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0, proc.stderr.read()


def test_view_from_python(repo, tmp_path):
    """``gscache.view`` serves a scene in memory: its URL carries a token, the page answers
    with it and refuses without it, and the handle shows as an IFrame in Jupyter."""
    import urllib.error
    import urllib.request

    import gscache

    scene = gscache.Scene.load(str(repo / "data/scenes/default.toml"))
    v = gscache.view(scene, output=str(tmp_path / "out"))
    try:
        assert v.url.startswith("http://127.0.0.1:") and "token=" in v.url
        with urllib.request.urlopen(v.url, timeout=10) as r:
            assert r.status == 200 and b"gscache view" in r.read()
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(v.url.split("?")[0], timeout=10)
        assert refused.value.code == 403
        assert v._repr_html_().startswith("<iframe src=\"http://127.0.0.1:")
    finally:
        v.stop()
    assert not (tmp_path / "out").exists(), "nothing is written before a Save"
    # The program's --denoise, --denoise-until and --scale, checked as the program checks them.
    with pytest.raises(ValueError, match="denoise `sometimes`"):
        gscache.view(scene, denoise="sometimes")
    with pytest.raises(ValueError, match="scale NaN: expected 0.1 to 2"):
        gscache.view(scene, scale=float("nan"))
    gscache.view(scene, denoise="off", denoise_until=8, scale=0.25).stop()


def test_reload_keeps_the_state_and_an_intensity_edit_keeps_the_light(viewer, browser, tmp_path):
    """Issue 49, items 1 and 5: a reloaded page shows the split view the server still renders
    (its box was unticked), and an edit of a light's intensity leaves its place as the scene
    file has it, bit for bit, in the saved scene (rebuilt from sliders in whole degrees it
    moved [70, 80, 60] to [69.81, 80.20, 59.96])."""
    import tomllib

    d = browser
    d.get(viewer)
    settled(d)
    d.find_element("id", "split").click()
    wait(lambda: "split: left NEE" in d.find_element("id", "stats").text, "the split view")
    k = d.find_element("css selector", "#lights input[data-k=k]")
    d.execute_script("arguments[0].value = 2;"
                     "arguments[0].dispatchEvent(new Event('input', {bubbles: true}));", k)
    d.find_element("id", "save").click()
    said = wait(lambda: (t := d.find_element("id", "error").text).startswith("saved:") and t,
                "the save")
    scene_file = next(f for f in said[len("saved:"):].split(",") if f.strip().endswith(".toml"))
    saved = tomllib.loads(open(scene_file.strip()).read())
    assert saved["light"][0]["center"] == [70.0, 80.0, 60.0], saved["light"][0]
    assert saved["light"][0]["radiance"] == [1000.0, 920.0, 840.0], saved["light"][0]
    d.refresh()
    wait(lambda: "spp" in d.find_element("id", "stats").text, "the reloaded page's first frame")
    assert d.find_element("id", "split").is_selected(), "the reloaded page unticked the split view"


def test_a_bad_field_is_named_set_back_and_does_not_block_the_next_edit(viewer, browser):
    """Issue 49, item 2: a window's low end above its high end is refused alone, and the field
    shows the value in force again, so the next edit (the density) applies; a field that is
    not a number is named, not sent."""
    d = browser
    d.get(viewer)
    first = settled(d)
    low = d.find_element("id", "window-lo")
    in_force = low.get_attribute("value")
    d.execute_script("arguments[0].value = 1000;"
                     "arguments[0].dispatchEvent(new Event('change'));", low)
    wait(lambda: "window" in d.find_element("id", "error").text, "the window's error")
    wait(lambda: low.get_attribute("value") == in_force, "the field set back")
    density = d.find_element("id", "density")
    d.execute_script("arguments[0].value = 'abc';"
                     "arguments[0].dispatchEvent(new Event('change'));", density)
    wait(lambda: "density scale: expected a number" in d.find_element("id", "error").text,
         "the named error")
    d.execute_script("arguments[0].value = 10 * arguments[0].value;"
                     "arguments[0].dispatchEvent(new Event('change'));", density)
    # (Measured: 3.0 grey levels on average over the 16x9 read-back; two converged frames of one
    # view differ by well under 1.)
    wait(lambda: differ(settled(d), first) > 1.5, "the density edit to change the image")
    assert "window" not in d.find_element("id", "error").text


def test_two_pages_show_one_view(viewer, browser):
    """Issue 49, item 3: every page shows the one view: a colour map chosen in one tab shows
    in the other's menu (it reverted the first tab's image while its menu kept the old one)."""
    from selenium.webdriver.support.ui import Select

    d = browser
    d.get(viewer)
    settled(d)
    first = d.current_window_handle
    d.switch_to.new_window("tab")
    d.get(viewer)
    settled(d)
    Select(d.find_element("id", "colormap")).select_by_value("inferno")
    d.switch_to.window(first)
    wait(lambda: Select(d.find_element("id", "colormap")).first_selected_option
         .get_attribute("value") == "inferno", "the other page's menu to follow")


def test_the_layout_follows_the_window_and_shows_what_applies(viewer, browser):
    """Issue 49, item 7: in a narrow window the view takes the width (it was 135 px of 500),
    the cache's controls show only with a cache method, the split view's halves are labelled,
    and a slider shows its value."""
    from selenium.webdriver.support.ui import Select

    d = browser
    d.set_window_size(500, 900)
    d.get(viewer)
    settled(d)
    width = d.execute_script("return [document.getElementById('frame').getBoundingClientRect()"
                             ".width, window.innerWidth];")
    assert width[0] >= 0.9 * width[1], width
    cache = d.find_element("id", "cache-section")
    assert not cache.is_displayed()
    Select(d.find_element("id", "method")).select_by_value("cache")
    assert cache.is_displayed()
    d.find_element("id", "split").click()
    labels = d.find_element("id", "split-labels")
    assert labels.is_displayed() and "cache" in labels.text and "NEE" in labels.text
    env = d.find_element("id", "environment")
    d.execute_script("arguments[0].value = 2.5;"
                     "arguments[0].dispatchEvent(new Event('input'));", env)
    assert d.find_element("id", "environment-value").text == "2.5"


def test_clipping_from_the_page_changes_the_image_and_the_saved_scene_renders_it(
        viewer, browser):
    """Issue 49, item 10: the clip box's sliders and the clip plane cut the volume in the view;
    the saved scene holds the clipping (a reloaded page shows it), and `gscache render` of the
    saved scene renders the clipped volume (its image differs from the unclipped scene's the
    way the view's did)."""
    import tomllib

    d = browser
    d.get(viewer)
    first = settled(d)
    d.find_element("css selector", "#clip-section summary").click()
    # The x axis kept from 0.5 of the box on, and a plane through the centre.
    slider = d.find_element("css selector", "[data-clip=x0]")
    d.execute_script("arguments[0].value = 0.5;"
                     "arguments[0].dispatchEvent(new Event('input', {bubbles: true}));", slider)
    # (Measured: 2.3 grey levels of 255 on average over the 16x9 read-back.)
    wait(lambda: differ(settled(d), first) > 1, "the clip box to change the image")
    boxed = settled(d)
    d.find_element("id", "clip-plane").click()
    wait(lambda: differ(settled(d), boxed) > 1, "the clip plane to change the image")
    d.find_element("id", "save").click()
    said = wait(lambda: (t := d.find_element("id", "error").text).startswith("saved:") and t,
                "the save")
    files = [f.strip() for f in said[len("saved:"):].split(",")]
    scene_file = next(f for f in files if f.endswith(".toml"))
    saved = tomllib.loads(open(scene_file).read())
    assert saved["clip"]["box"]["min"][0] == 0.0, saved["clip"]  # the default box is centred
    assert len(saved["clip"]["plane"]) == 1, saved["clip"]
    # A reloaded page shows the clipping in force (its section open, as it is in use).
    d.refresh()
    wait(lambda: "spp" in d.find_element("id", "stats").text, "the reloaded page's first frame")
    assert d.find_element("id", "clip-section").get_attribute("open") is not None
    assert d.find_element("id", "clip-plane").is_selected()
    assert float(d.find_element("css selector", "[data-clip=x0]").get_attribute("value")) == 0.5
    # The saved scene renders clipped: against the same scene with its clipping cleared, the
    # mean brightness moves (half the volume is cut away).
    import gscache
    saved_scene = gscache.Scene.load(scene_file)
    assert saved_scene.clip == saved["clip"]
    clipped = gscache.render(saved_scene, spp=8)
    unclipped = gscache.render(saved_scene.clipped(), spp=8)
    assert abs(float(clipped.mean()) - float(unclipped.mean())) > 0.02 * float(unclipped.mean())


def test_the_page_probes_keeps_views_and_draws_its_guides(viewer, browser, repo):
    """Issue 49, items 8, 9 and 11: a click on the image reports the voxel the camera's ray
    first meets in visible medium, with the value a voxel lookup of the file gives there; the
    data panel names the volume; the colour bar is drawn; a view along an axis changes the
    image, and a kept view is listed and brings the camera back."""
    import re

    import numpy as np
    from selenium.webdriver import ActionChains

    d = browser
    d.get(viewer)
    first = settled(d)
    d.find_element("css selector", "#data-section summary").click()
    assert "neghip_64x64x64_uint8.raw" in d.find_element("id", "data").text
    assert "64 x 64 x 64 voxels, uint8" in d.find_element("id", "data").text
    # A click in the middle of the view (the volume's centre is there).
    ActionChains(d).move_to_element(d.find_element("id", "view")).click().perform()
    text = wait(lambda: (t := d.find_element("id", "probe").text).startswith("at (") and t,
                "the probe's answer")
    voxel = [int(v) for v in re.search(r"voxel \((\d+), (\d+), (\d+)\)", text).groups()]
    value = float(re.search(r"value ([-\d.e]+)", text).group(1))
    raw = np.fromfile(repo / "data/volumes/neghip_64x64x64_uint8.raw", dtype=np.uint8)
    x, y, z = voxel
    assert value == raw.reshape(64, 64, 64)[z, y, x], (text, raw.reshape(64, 64, 64)[z, y, x])
    assert value > 0
    # A click is not a drag: the image did not restart from a new camera.
    assert differ(settled(d), first) < 1
    # The colour bar shows the transfer function's colours (not blank).
    spread = d.execute_script(
        "const c = document.getElementById('colour-bar');"
        "const p = c.getContext('2d').getImageData(0, 0, c.width, 1).data;"
        "let lo = 255, hi = 0; for (let i = 0; i < p.length; i += 4) {"
        "  const v = p[i] + p[i + 1] + p[i + 2]; lo = Math.min(lo, v); hi = Math.max(hi, v); }"
        "return hi - lo;")
    assert spread > 30, spread
    # Keep this view, look along +x, then go back to the kept view.
    d.find_element("id", "view-name").send_keys("start")
    d.find_element("id", "view-keep").click()
    kept = wait(lambda: d.find_elements("css selector", "#views button"), "the kept view")
    assert kept[0].text == "start"
    d.find_element("css selector", "#axis-views button[title='view from +x']").click()
    wait(lambda: differ(settled(d), first) > 3, "the view along +x")
    d.find_element("css selector", "#views button").click()
    wait(lambda: differ(settled(d), first) < 1, "the kept view's image again")
