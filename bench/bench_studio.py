"""Patternshop Studio benchmark: brush latency in the browser, edit to points, server memory.

A real server (``patternshop studio``, one synthesis thread) in a child process, measured three ways:

* **brush stroke to repaint** on a 1024 x 1024 map, in headless Chromium: for each of 100 strokes
  (size 40 px, 6 stamps 8 px apart, dispatched as pointer events on the map view), the time from the
  ``pointerdown`` to the end of the animation frame that paints the first stamp (the page draws in
  ``requestAnimationFrame``, so this includes the wait for the next frame, up to 16.7 ms at 60 Hz), the
  handler's own time, and the time to the frame after the whole stroke; medians, and the server's time
  per acknowledged stroke (the strokes queue behind one another);
* **edit to points**: a density stroke, then ``POST /api/synthesize`` of 20,000 points; the time from the
  edit's request to the first points ``/api/points.bin`` serves (the quick density-matched preview), to the
  first frame of the synthesis itself (its density-matched start or a later iteration) and to the final points, polled every 0.12 s as the page does; on the logo map (384 x 256) and on the 1024 x 1024
  map; and the same synthesis in-process without a server (``api.synthesize``), for the server's overhead;
* **edit to points after a local edit**: the same, a second time, once a synthesis of the map exists: the studio
  then re-makes only a window around the edit (:mod:`patternshop.studio.incremental`); the first frame is the
  kept points plus the new ones drawn in the edited region;
* **local vs full, in-process** (``local_vs_full``): for edits of the 1024 x 1024 map and the logo, the local
  update's time and the full synthesis's, and the points in the changed pixels of each compared with the
  independent statistics of ``fidelity_stats`` (count against the map's expectation, nearest-neighbour distances
  in local r_max units: mean, coefficient of variation, minimum, stacked pairs); with ``--threshold``, density
  fills of growing squares on the 1024 x 1024 map (where a local update stops paying: ``MAX_WINDOW_SHARE``);
* **server memory** (resident, from /proc) before and at its peak during a 100,000-point synthesis.

Targets (issue 30; quiet machine, one thread): stroke to repaint <= 30 ms median; edit to first points
<= 1 s, to the final 20,000 points <= 3 s. The machine is shared: the load average is recorded.
The browser part is skipped (with a note in the results) when chromium, chromedriver or selenium is
missing. Run ``python bench/bench_studio.py [--strokes N] [--threshold]``; results go to ``out/bench/studio.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
from common import save_results  # bench/ is on sys.path when run as a script

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


class Server:
    """``patternshop studio FILE`` in a child process; ``call`` speaks its API."""

    def __init__(self, map_path: Path, project: Path) -> None:
        env = {**os.environ, "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
        start = time.perf_counter()
        self.process = subprocess.Popen([sys.executable, "-m", "patternshop", "studio", str(map_path), "--no-browser",
                                         "--port", "0", "--project", str(project), "--max-memory-gb", "8"],
                                        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=ROOT, env=env)
        match = re.search(r"(http://\S+)", self.process.stdout.readline())
        if match is None:
            self.process.kill()
            raise SystemExit("the studio printed no URL")
        self.url = match.group(1)
        self.start_s = round(time.perf_counter() - start, 3)  # process start to the printed URL
        self.base, self.token = self.url.split("/?token=")

    def call(self, path: str, body: object = None, data: bytes | None = None) -> object:
        payload = data if data is not None else (None if body is None else json.dumps(body).encode())
        request = urllib.request.Request(self.base + path, data=payload, headers={"X-Patternshop-Token": self.token},
                                         method="GET" if payload is None else "POST")
        with urllib.request.urlopen(request, timeout=600) as response:
            return json.loads(response.read())

    def points(self, since: int) -> tuple[dict, bytes]:
        request = urllib.request.Request(f"{self.base}/api/points.bin?since={since}", headers={"X-Patternshop-Token": self.token})
        with urllib.request.urlopen(request, timeout=600) as response:
            return json.loads(response.headers["X-Points"]), response.read()

    def rss_mb(self) -> float:
        for line in Path(f"/proc/{self.process.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
        return float("nan")

    def stop(self) -> None:
        self.process.terminate()
        self.process.wait(20)


def wait_done(server: Server, timeout: float = 600.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = server.call("/api/status")
        if status["job"]["state"] != "running":
            return status
        time.sleep(0.05)
    raise SystemExit("synthesis did not finish")


def edit_to_points(server: Server, points: int, x: float, y: float) -> dict:
    """A density stroke, then a synthesis of ``points``: seconds from the edit to the first and the final points."""
    frame = server.points(0)[0]["frame"]
    start = time.perf_counter()
    server.call("/api/edit", {"type": "density", "centres": [[x, y], [x + 20, y]], "size": 30, "strength": 0.3})
    server.call("/api/synthesize", {"points": points})
    first = own = final = None
    while final is None:  # as the page polls
        meta, body = server.points(frame)
        now = time.perf_counter() - start
        if body:
            frame = meta["frame"]
            first = now if first is None else first
            if own is None and not meta.get("preview"):
                own = now
            if meta["final"]:
                final = now
        elif meta["status"]["job"]["state"] in ("error", "cancelled"):
            raise SystemExit(f"synthesis failed: {meta['status']['text']}")
        time.sleep(0.12)
    status = server.call("/api/status")
    return {"points": points, "final_points": meta["n"], "local": status["job"]["local"],
            "edit_to_first_points_s": round(first, 3), "edit_to_synthesis_own_points_s": round(own, 3),
            "edit_to_final_points_s": round(final, 3)}


def region_statistics(xy: np.ndarray, lab: np.ndarray, region: np.ndarray) -> dict:
    """The points (n, 2) of a map (H, W, 3) in a region (H, W) bool, measured by ``fidelity_stats``: their count over
    the map's expectation and their nearest-neighbour distances (to any point) in local r_max units."""
    from fidelity_stats import STACKED, Intensity, nearest_neighbours

    side = max(lab.shape[:2])
    density = np.clip(1.0 - lab[..., 0].astype(np.float64) / 100.0, 0.0, 1.0)
    intensity = Intensity(density, (lab.shape[1] / side, lab.shape[0] / side), len(xy))
    col = np.clip((xy[:, 0] * side).astype(np.int64), 0, lab.shape[1] - 1)
    row = np.clip((xy[:, 1] * side).astype(np.int64), 0, lab.shape[0] - 1)
    inside = region[row, col]
    nn = nearest_neighbours(xy, intensity.domain)[inside] / intensity.local_r_max(xy[inside])
    return {"points": int(inside.sum()), "count_over_expected": round(inside.sum() / (len(xy) * density[region].sum()
                                                                                      / density.sum()), 3),
            "nn_mean": round(float(nn.mean()), 3), "nn_cv": round(float(nn.std() / nn.mean()), 3),
            "nn_min": round(float(nn.min()), 3), "stacked": int(np.sum(nn < STACKED))}


def local_vs_full(lab_map: object, edits: dict[str, dict], points: int = 20_000) -> dict:
    """In-process, one thread: a full synthesis of ``points`` (the base), then per edit the local update and a
    full synthesis of the edited map, timed, and their points in the changed pixels measured."""
    from patternshop import api
    from patternshop.studio.incremental import Base, plan_local_update
    from patternshop.studio.tools import apply_edit
    from synthesis.synthesize import point_count, points_per_ink_of

    lab = np.asarray(lab_map.lab)
    per_ink = points_per_ink_of(lab_map, points)
    base = Base(lab, api.synthesize(lab_map, points=points).points.xy, 0, ("ink", per_ink))
    rows = {}
    for name, edit in edits.items():
        edited = apply_edit(lab, edit).lab
        n = point_count(api.LabMap(edited), per_ink)
        start = time.perf_counter()
        plan = plan_local_update(base, edited, n, 0, ("ink", per_ink), max_window_share=1.0)
        local, _ = plan.run(0)
        local_s = time.perf_counter() - start
        start = time.perf_counter()
        full = api.synthesize(api.LabMap(edited), points=n).points.xy
        full_s = time.perf_counter() - start
        changed = np.any(edited != lab, axis=2)
        window = np.zeros_like(changed)  # the whole window, with the seam between refined and kept points
        window[plan.box[0] : plan.box[1], plan.box[2] : plan.box[3]] = True
        rows[name] = {"changed_share": round(plan.changed_share, 4), "window_share": round(plan.window_share, 4),
                      "window_points": len(plan.start), "iterations": plan.iterations, "n_local": len(local), "n_full": n,
                      "local_s": round(local_s, 2), "full_s": round(full_s, 2),
                      "local_changed_region": region_statistics(local, edited, changed),
                      "full_changed_region": region_statistics(full, edited, changed),
                      "local_window": region_statistics(local, edited, window),
                      "full_window": region_statistics(full, edited, window),
                      "load_average": os.getloadavg()}
        print(name, json.dumps(rows[name]), flush=True)
    return rows


def memory_during(server: Server, points: int) -> dict:
    before = server.rss_mb()
    server.call("/api/synthesize", {"points": points})
    peak, start = before, time.perf_counter()
    while server.call("/api/status")["job"]["state"] == "running":
        peak = max(peak, server.rss_mb())
        time.sleep(0.1)
    status = server.call("/api/status")
    return {"points": points, "rss_before_mb": round(before), "rss_peak_mb": round(peak),
            "seconds": round(time.perf_counter() - start, 2), "status": status["text"]}


BRUSH_SCRIPT = """
const [count, done] = [arguments[0], arguments[arguments.length - 1]];
const canvas = document.getElementById('map-view');
const rect = canvas.getBoundingClientRect();
const frame = () => new Promise((resolve) => requestAnimationFrame(resolve));  // after the page's own draw
const at = (x, y) => ({clientX: rect.left + (x * S.view.zoom + S.view.x) * rect.width / canvas.width,
                       clientY: rect.top + (y * S.view.zoom + S.view.y) * rect.height / canvas.height});
const fire = (type, x, y) => canvas.dispatchEvent(new PointerEvent(type, {...at(x, y), button: 0, buttons: 1,
                                                                          pointerId: 1, bubbles: true}));
(async () => {
  saveSetting('tool', 'density'); saveSetting('size', 40); saveSetting('strength', 0.3); applySettingsToControls();
  const first = [], whole = [], handler = [];
  for (let k = 0; k < count; k++) {
    const x = 100 + (k % 10) * 80, y = 100 + Math.floor(k / 10) * 80;
    const t0 = performance.now();
    fire('pointerdown', x, y);
    handler.push(performance.now() - t0);
    await frame();
    first.push(performance.now() - t0);
    for (let m = 1; m <= 5; m++) fire('pointermove', x + 8 * m, y);
    fire('pointerup', x + 40, y);
    await frame();
    whole.push(performance.now() - t0);
  }
  const t1 = performance.now();
  await S.queue;
  done({first, whole, handler, server_wait_ms: performance.now() - t1});
})();
"""


def brush_latency(server: Server, strokes: int) -> dict:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_path = shutil.which("chromedriver")
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        return {"skipped": "selenium is not installed"}
    if not chromium or not driver_path:
        return {"skipped": "chromium or chromedriver not found"}
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for argument in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1440,900",
                     "--force-device-scale-factor=1"):
        options.add_argument(argument)
    driver = webdriver.Chrome(service=Service(executable_path=driver_path), options=options)
    try:
        driver.set_script_timeout(600)
        start = time.perf_counter()
        driver.get(server.url)
        while not driver.execute_script("return document.body.dataset.ready === 'true'"):
            time.sleep(0.02)
        load = time.perf_counter() - start
        result = driver.execute_async_script(BRUSH_SCRIPT, strokes)
        difference = driver.execute_async_script(
            "const done = arguments[arguments.length - 1];"
            "api('/api/map.lab', {raw: true}).then((r) => r.arrayBuffer()).then((b) => { const s = new Float32Array(b);"
            "let m = 0; for (let i = 0; i < s.length; i++) m = Math.max(m, Math.abs(s[i] - S.map.lab[i])); done(m); });")
    finally:
        driver.quit()
    return {"strokes": strokes, "page_load_to_ready_s": round(load, 3),
            "stamp_handler_ms_median": round(statistics.median(result["handler"]), 2),
            "stroke_to_first_repaint_ms_median": round(statistics.median(result["first"]), 1),
            "whole_stroke_to_repaint_ms_median": round(statistics.median(result["whole"]), 1),
            "stroke_to_first_repaint_ms_p90": round(sorted(result["first"])[int(0.9 * len(result["first"]))], 1),
            "server_ms_per_stroke": round((sum(result["whole"]) + result["server_wait_ms"]) / strokes, 1),
            "page_and_server_maps_max_difference": difference}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--strokes", type=int, default=100)
    parser.add_argument("--threshold", action="store_true", help="also local vs full for growing square fills")
    args = parser.parse_args()
    from patternshop import api

    results: dict = {"load_average_before": os.getloadavg()}
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        big = folder / "big.tif"
        big_map = api.uniform_map(1024, density=0.3, correlation="blue")
        api.write_map(big_map, big)
        server = Server(big, folder / "project-big")
        try:
            results["map_1024"] = {"brush": brush_latency(server, args.strokes),
                                   "synthesis": edit_to_points(server, 20_000, 500, 500),
                                   "synthesis_after_local_edit": edit_to_points(server, 20_000, 200, 700)}
        finally:
            server.stop()
        server = Server(ROOT / "examples" / "logo.tif", folder / "project-logo")
        try:
            edit_to_points(server, 2_000, 100, 30)  # warm: the kernels are compiled or loaded once per process
            results["logo_384x256"] = {"server_start_s": server.start_s,
                                       "synthesis": edit_to_points(server, 20_000, 300, 30),
                                       "synthesis_after_local_edit": edit_to_points(server, 20_000, 60, 200),
                                       "memory": memory_during(server, 100_000)}
        finally:
            server.stop()
        logo = api.read_map(ROOT / "examples" / "logo.tif")
        api.synthesize(logo, points=2_000, iterations=5)  # warm
        start = time.perf_counter()
        api.synthesize(logo, points=20_000)
        results["logo_384x256"]["synthesis"]["in_process_without_server_s"] = round(time.perf_counter() - start, 3)
    stroke = {"type": "density", "size": 30, "strength": 0.3}
    results["local_vs_full"] = {
        "map_1024": local_vs_full(big_map, {
            "stroke": {**stroke, "centres": [[500, 500], [520, 500]]},
            "fill_200px": {"type": "fill", "rect": [100, 600, 300, 800], "density": 0.6},
            "colour_fill_200px": {"type": "fill", "rect": [600, 100, 800, 300], "ab": list(api.preset("green"))}}),
        "logo_384x256": local_vs_full(logo, {"stroke": {**stroke, "centres": [[300, 30], [320, 30]]},
                                             "fill_100px": {"type": "fill", "rect": [40, 60, 140, 160], "density": 0.7}})}
    if args.threshold:
        results["local_vs_full"]["threshold_1024"] = local_vs_full(big_map, {
            f"square_{2 * half}px": {"type": "fill", "rect": [512 - half, 512 - half, 512 + half, 512 + half], "density": 0.5}
            for half in (50, 120, 200, 300, 400, 512)})
    results["load_average_after"] = os.getloadavg()
    save_results("studio", results)


if __name__ == "__main__":
    main()
