"""Patternshop Studio in a real browser: headless Chromium driven by Selenium (Debian's chromium + chromium-driver).

One user flow on a real server (``patternshop studio examples/logo.tif``): paint density, pick a colour in the
palette and paint it, synthesise and see dots in the points view (canvas pixels read back), undo, export the
points, reload the page and find the same state. Screenshots go to out/studio/; with
``PATTERNSHOP_UPDATE_DOCS=1`` a small copy also replaces docs/studio.png, the one docs/studio.md shows.

Skips when chromium, chromedriver or selenium is missing, except under CI (``CI=true``), where that fails.
Install: ``apt-get install -y --no-install-recommends chromium chromium-driver`` and ``pip install selenium``.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
CHROMIUM = os.environ.get("PATTERNSHOP_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = os.environ.get("PATTERNSHOP_CHROMEDRIVER") or shutil.which("chromedriver")
IN_CI = os.environ.get("CI", "").lower() == "true"
POINTS = 4000


def _missing() -> str | None:
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install selenium)"
    if not CHROMIUM or not CHROMEDRIVER:
        return ("chromium or chromedriver not found (apt-get install -y --no-install-recommends chromium "
                "chromium-driver, or set PATTERNSHOP_CHROMIUM / PATTERNSHOP_CHROMEDRIVER)")
    return None


MISSING = _missing()
if MISSING:
    if IN_CI:
        pytest.fail(f"browser tests cannot run under CI=true: {MISSING}", pytrace=False)
    pytest.skip(f"studio browser tests skipped: {MISSING}", allow_module_level=True)

from selenium import webdriver  # noqa: E402
from selenium.webdriver.chrome.service import Service  # noqa: E402
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    project = tmp_path_factory.mktemp("studio-project")
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    process = subprocess.Popen([sys.executable, "-m", "patternshop", "studio", str(ROOT / "examples" / "logo.tif"),
                                "--no-browser", "--port", "0", "--project", str(project)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env)
    line = process.stdout.readline()
    match = re.search(r"(http://\S+)", line)
    if match is None:
        process.kill()
        pytest.fail(f"the studio printed no URL: {line!r} {process.stderr.read()}")
    yield match.group(1)
    process.terminate()
    process.communicate(timeout=20)


@pytest.fixture(scope="module")
def downloads(tmp_path_factory):
    return tmp_path_factory.mktemp("downloads")


@pytest.fixture(scope="module")
def driver(downloads):
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for argument in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1440,900",
                     "--force-device-scale-factor=1"):
        options.add_argument(argument)
    options.add_experimental_option("prefs", {"download.default_directory": str(downloads),
                                              "download.prompt_for_download": False})
    browser = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=options)
    browser.execute_cdp_cmd("Browser.setDownloadBehavior", {"behavior": "allow", "downloadPath": str(downloads)})
    browser.set_script_timeout(30)
    yield browser
    browser.quit()


def by_testid(driver, name: str):
    return driver.find_element(By.CSS_SELECTOR, f'[data-testid="{name}"]')


def wait_ready(driver) -> None:
    WebDriverWait(driver, 30).until(lambda d: d.execute_script("return document.body.dataset.ready === 'true'"))
    time.sleep(0.2)  # a frame for the canvases


def wait_idle(driver) -> None:
    """Until every edit the page sent has its answer."""
    driver.execute_async_script("const done = arguments[arguments.length - 1]; S.queue.then(() => setTimeout(done, 100));")


def screen_of(driver, x: float, y: float) -> tuple[float, float]:
    """CSS offset from the centre of a view for map pixel (x, y) (both views share the transform)."""
    return driver.execute_script(
        "const c = document.getElementById('map-view'); const r = c.getBoundingClientRect();"
        "const k = r.width / c.width;"
        "return [(arguments[0] * S.view.zoom + S.view.x) * k - r.width / 2, (arguments[1] * S.view.zoom + S.view.y) * k - r.height / 2];",
        x, y)


def pixel(driver, view: str, x: float, y: float) -> list[int]:
    """The RGBA of canvas ``view`` where map pixel (x, y) is shown."""
    return driver.execute_script(
        "const c = document.getElementById(arguments[0]);"
        "const sx = Math.floor(arguments[1] * S.view.zoom + S.view.x), sy = Math.floor(arguments[2] * S.view.zoom + S.view.y);"
        "return Array.from(c.getContext('2d').getImageData(sx, sy, 1, 1).data);", view, x, y)


def dark_pixels(driver) -> int:
    return driver.execute_script(
        "const c = document.getElementById('points-view'); const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
        "let n = 0; for (let i = 0; i < d.length; i += 4) if (d[i + 3] > 200 && d[i] < 100 && d[i + 1] < 100 && d[i + 2] < 100) n++; return n;")


def stroke(driver, points: list[tuple[float, float]]) -> None:
    canvas = by_testid(driver, "map-view")
    actions = ActionChains(driver, duration=20)
    x, y = screen_of(driver, *points[0])
    actions.move_to_element_with_offset(canvas, int(x), int(y)).click_and_hold()
    for point in points[1:]:
        x, y = screen_of(driver, *point)
        actions.move_to_element_with_offset(canvas, int(x), int(y))
    actions.release().perform()


def largest_difference_from_server(driver) -> float:
    """max |page's map - server's map| over every L, a, b value."""
    return driver.execute_async_script(
        "const done = arguments[arguments.length - 1];"
        "api('/api/map.lab', {raw: true}).then((r) => r.arrayBuffer()).then((buffer) => {"
        "  const server = new Float32Array(buffer); let m = server.length === S.map.lab.length ? 0 : Infinity;"
        "  for (let i = 0; i < server.length; i++) m = Math.max(m, Math.abs(server[i] - S.map.lab[i])); done(m); });")


def synthesize_and_wait(driver, words: str) -> None:
    """Click *Synthesize*; wait until a new job is over and the status line says ``words``."""
    job = server_state(driver)["status"]["job"].get("job", 0)
    by_testid(driver, "synthesize").click()
    WebDriverWait(driver, 90).until(lambda d: server_state(d)["status"]["job"].get("job", 0) > job
                                    and words in by_testid(d, "status").text)


def synthesised_points(driver) -> np.ndarray:
    """(n, 2) the last synthesised points, as GET /api/points.txt serves them."""
    text = driver.execute_async_script(
        "const done = arguments[arguments.length - 1]; api('/api/points.txt', {raw: true}).then((r) => r.text()).then(done);")
    return np.array([[float(v) for v in line.split()] for line in text.splitlines() if line and not line.startswith("#")])


def server_state(driver) -> dict:
    return driver.execute_async_script("const done = arguments[arguments.length - 1]; api('/api/state').then(done);")


def test_user_flow(driver, server, downloads):
    out = ROOT / "out" / "studio"
    out.mkdir(parents=True, exist_ok=True)
    driver.get(server)
    wait_ready(driver)
    assert "logo.tif" in by_testid(driver, "status").text
    # 1. paint density: a dark stroke across the light background at the top of the logo map (384 x 256)
    by_testid(driver, "tool-density").click()
    driver.execute_script("saveSetting('strength', 1.0); saveSetting('size', 24); saveSetting('hardness', 0.8); applySettingsToControls();")
    spot = (330.0, 30.0)
    before = pixel(driver, "map-view", *spot)
    stroke(driver, [(300.0, 30.0), (330.0, 30.0), (360.0, 30.0)])
    painted = pixel(driver, "map-view", *spot)
    assert sum(painted[:3]) < sum(before[:3]) - 150, (before, painted)  # repainted at once, before any reload
    wait_idle(driver)
    assert server_state(driver)["undo"][-1] == "density brush (darken)"
    assert largest_difference_from_server(driver) < 1e-3  # the page painted what the server applied
    # 2. the palette: hovering shows a pattern, a click makes the colour current; paint it
    info = driver.execute_script("return [S.picture, S.presets.green];")
    picture, (a, b) = info
    image = by_testid(driver, "palette")
    size = image.size
    u, v = (a + 128) / 255, (127 - b) / 255
    px = (picture["left"] + u * picture["side"]) / picture["width"] * size["width"] - size["width"] / 2
    py = (picture["top"] + v * picture["side"]) / picture["height"] * size["height"] - size["height"] / 2
    ActionChains(driver).move_to_element_with_offset(image, int(px), int(py)).perform()
    WebDriverWait(driver, 10).until(lambda d: "green" in by_testid(d, "hover-label").text)
    hover_dots = driver.execute_script(
        "const c = document.getElementById('palette-hover'); const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
        "let n = 0; for (let i = 0; i < d.length; i += 4) if (d[i] < 60) n++; return n;")
    assert hover_dots > 200  # the example pattern is drawn
    ActionChains(driver).move_to_element_with_offset(image, int(px), int(py)).click().perform()
    assert "green" in driver.find_element(By.ID, "current-label").text
    assert "active" in by_testid(driver, "tool-correlation").get_attribute("class")
    colour_spot = (200.0, 240.0)  # the light blue-noise background below, between the disc and the P
    before_colour = pixel(driver, "map-view", *colour_spot)
    stroke(driver, [(170.0, 240.0), (230.0, 240.0)])
    after_colour = pixel(driver, "map-view", *colour_spot)
    assert after_colour[1] > after_colour[2] + 20 and after_colour != before_colour, (before_colour, after_colour)  # greener
    wait_idle(driver)
    assert server_state(driver)["undo"][-1] == "correlation brush"
    assert largest_difference_from_server(driver) < 1e-3
    # 3. synthesise: dots appear in the points view, the status says how many
    assert dark_pixels(driver) == 0
    count = by_testid(driver, "points-count")
    count.clear()
    count.send_keys(str(POINTS))
    by_testid(driver, "synthesize").click()
    WebDriverWait(driver, 90).until(lambda d: re.search(rf"\b{POINTS} points\b", by_testid(d, "status").text)
                                    and d.execute_script("return S.timing.final !== null;"))  # the final points shown
    time.sleep(0.3)
    dots = dark_pixels(driver)
    assert dots > POINTS, dots  # every point a dot of a few pixels
    timing = driver.execute_script("return S.timing;")
    print(f"click to first points {timing['firstPoints']:.0f} ms (partial: {timing['firstWasPartial']}), "
          f"to all {POINTS} points {timing['final']:.0f} ms")
    assert timing["firstWasPartial"] and timing["firstPoints"] < timing["final"]  # the points streamed in
    # ... by Server-Sent Events: the EventSource is open (the page polls only once it has failed for good)
    assert driver.execute_script("return S.events !== null && S.events.readyState === EventSource.OPEN && !S.polling;")
    driver.save_screenshot(str(out / "studio_after_synthesis.png"))
    # 4. undo the colour stroke: the map shows the old colour again
    by_testid(driver, "undo").click()
    wait_idle(driver)
    time.sleep(0.2)
    assert pixel(driver, "map-view", *colour_spot) == before_colour
    state = server_state(driver)
    assert state["undo"][-1] == "density brush (darken)" and state["redo"] == ["correlation brush"]
    # 5. export the points: a download of the synthesised points
    by_testid(driver, "export-points").click()
    deadline = time.monotonic() + 20
    while not list(downloads.glob("*.points.txt")) and time.monotonic() < deadline:
        time.sleep(0.1)
    exported = list(downloads.glob("*.points.txt"))
    assert exported, list(downloads.iterdir())
    rows = [line for line in exported[0].read_text().splitlines() if line and not line.startswith("#")]
    assert len(rows) == POINTS
    # 6. reload: the same map, history, points, tool and colour
    view = driver.execute_script("return [S.view.zoom, S.view.x, S.view.y];")
    driver.execute_script("flushSettings();")
    time.sleep(0.3)
    driver.refresh()
    wait_ready(driver)
    assert driver.execute_script("return [S.view.zoom, S.view.x, S.view.y];") == pytest.approx(view)
    assert pixel(driver, "map-view", *spot) == painted
    assert pixel(driver, "map-view", *colour_spot) == before_colour
    assert by_testid(driver, "undo").is_enabled() and by_testid(driver, "redo").is_enabled()
    assert "green" in driver.find_element(By.ID, "current-label").text
    assert "active" in by_testid(driver, "tool-correlation").get_attribute("class")
    assert re.search(rf"\b{POINTS} points\b", by_testid(driver, "status").text)
    assert abs(dark_pixels(driver) - dots) < 0.05 * dots
    # redo brings the colour back; the screenshot for the docs shows the whole flow's result
    by_testid(driver, "redo").click()
    wait_idle(driver)
    time.sleep(0.3)
    assert pixel(driver, "map-view", *colour_spot) == after_colour
    driver.save_screenshot(str(out / "studio.png"))
    # 7. auto mode: a density gradient (drawn with the gradient tool) is synthesised without a click
    job = server_state(driver)["status"]["job"]["job"]
    by_testid(driver, "auto").click()
    by_testid(driver, "tool-gradient").click()
    stroke(driver, [(0.0, 128.0), (192.0, 128.0), (383.0, 128.0)])
    WebDriverWait(driver, 90).until(lambda d: server_state(d)["status"]["job"].get("job", 0) > job
                                    and re.search(rf"Done: {POINTS} points", by_testid(d, "status").text))
    assert server_state(driver)["undo"][-1] == "density gradient"
    assert sum(pixel(driver, "map-view", 10.0, 128.0)[:3]) < sum(pixel(driver, "map-view", 370.0, 128.0)[:3])  # 0.8 -> 0.1
    # 8. lasso and magic wand fills with the current colour; the map under the points
    by_testid(driver, "auto").click()
    by_testid(driver, "tool-lasso").click()
    stroke(driver, [(250.0, 150.0), (300.0, 150.0), (300.0, 200.0), (250.0, 200.0)])
    wait_idle(driver)
    assert server_state(driver)["undo"][-1] == "lasso fill"
    lassoed = pixel(driver, "map-view", 280.0, 180.0)
    assert lassoed[1] > lassoed[2], lassoed  # green now
    by_testid(driver, "tool-wand").click()
    canvas = by_testid(driver, "map-view")
    x, y = screen_of(driver, 115.0, 128.0)  # the middle of the disc
    ActionChains(driver).move_to_element_with_offset(canvas, int(x), int(y)).click().perform()
    wait_idle(driver)
    assert server_state(driver)["undo"][-1] == "similar-colour fill"
    assert largest_difference_from_server(driver) == 0
    driver.execute_script("saveSetting('overlay', 0.5); draw();")
    time.sleep(0.2)
    coloured = driver.execute_script(
        "const c = document.getElementById('points-view'); const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
        "let n = 0; for (let i = 0; i < d.length; i += 4) if (d[i + 3] > 200 && Math.abs(d[i] - d[i + 2]) > 20) n++; return n;")
    assert coloured > 10_000, coloured  # the map shows under the dots
    driver.save_screenshot(str(out / "studio_tools.png"))
    # 9. a local edit after a synthesis: only the points near it are re-made, the others stay where they were
    driver.execute_script("saveSetting('overlay', 0); draw();")
    synthesize_and_wait(driver, "Done:")
    before = synthesised_points(driver)
    by_testid(driver, "tool-density").click()
    driver.execute_script("saveSetting('mode', 'lighten'); applySettingsToControls();")
    stroke(driver, [(40.0, 225.0), (60.0, 225.0)])  # lighten to white, bottom left (the gradient's dark end; size 24)
    wait_idle(driver)
    synthesize_and_wait(driver, "re-made locally")
    after = synthesised_points(driver)
    far = lambda xy: np.hypot(xy[:, 0] * 384 - 50, xy[:, 1] * 384 - 225) > 80  # map pixels from the stroke
    near = lambda xy: np.hypot(xy[:, 0] * 384 - 50, xy[:, 1] * 384 - 225) < 8
    np.testing.assert_array_equal(np.sort(before[far(before)], axis=0), np.sort(after[far(after)], axis=0))
    assert near(before).sum() > 5 and near(after).sum() <= 0.2 * near(before).sum(), (near(before).sum(), near(after).sum())
    time.sleep(0.3)
    driver.save_screenshot(str(out / "studio_local.png"))
    if os.environ.get("PATTERNSHOP_UPDATE_DOCS") != "1":
        return
    from PIL import Image

    with Image.open(out / "studio.png") as shot:
        small = shot.convert("RGB").resize((shot.width * 2 // 3, shot.height * 2 // 3), Image.Resampling.LANCZOS)
        small.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.FLOYDSTEINBERG).save(ROOT / "docs" / "studio.png", optimize=True)


def test_progress_falls_back_to_polling_when_the_event_stream_fails(driver, server):
    """With GET /api/events refused (a wrong token: 403), the EventSource errors for good and the page polls:
    a synthesis still ends with "Done: N points" and its dots."""
    script = driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": (
        "const RealEventSource = window.EventSource;"
        "window.EventSource = class extends RealEventSource { constructor(url) { super(url.replace('token=', 'token=wrong')); } };")})
    try:
        driver.get(server)
        wait_ready(driver)
        WebDriverWait(driver, 30).until(lambda d: d.execute_script("return S.events === null;"))
        synthesize_and_wait(driver, "Done:")
        assert re.search(r"Done: \d+ points", by_testid(driver, "status").text)
        assert driver.execute_script("return S.events === null;")
        time.sleep(0.3)
        assert dark_pixels(driver) > 100
    finally:
        driver.execute_cdp_cmd("Page.removeScriptToEvaluateOnNewDocument", {"identifier": script["identifier"]})
