"""Patternshop Studio's HTTP API (Starlette TestClient), its edits, its project folder, and kill -9 of a real server."""

from __future__ import annotations

import http.client
import io
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from helpers import random_map
from PIL import Image
from starlette.testclient import TestClient

from patternshop.studio import server
from patternshop.studio.project import Project
from patternshop.studio.server import Studio, create_app
from patternshop.studio.tools import apply_edit, stroke_weight
from synthesis.labmap import LabMap
from synthesis.mapio import read_map, write_tiff

ROOT = Path(__file__).resolve().parent.parent
BASE = "http://127.0.0.1:8765"
TOKEN = "test-token-123"


def tif_bytes(lab_map: LabMap, tmp_path: Path, bits: int = 16) -> bytes:
    path = tmp_path / "upload-source.tif"
    write_tiff(lab_map, path, bits=bits)
    return path.read_bytes()


def smooth_map(height: int = 32, width: int = 48) -> LabMap:
    """L from 30 to 80 left to right, blue-noise colour: a map with ink everywhere."""
    lab = np.zeros((height, width, 3), np.float32)
    lab[..., 0] = np.linspace(30, 80, width)[None, :]
    lab[..., 1:] = (24.0, -52.0)
    return LabMap(lab)


@pytest.fixture
def studio(tmp_path):
    project = Project(tmp_path / "project")
    studio = Studio(project, token=TOKEN, max_upload_bytes=200_000)
    yield studio
    studio.synthesizer.cancel("test over")
    studio.synthesizer.wait(30)
    project.close()


@pytest.fixture
def client(studio):
    with TestClient(create_app(studio), base_url=BASE, headers={"X-Patternshop-Token": TOKEN}) as client:
        yield client


@pytest.fixture
def opened(client, tmp_path):
    """A client whose project has the 48 x 32 smooth map open."""
    response = client.post("/api/open?name=smooth.tif", content=tif_bytes(smooth_map(), tmp_path))
    assert response.status_code == 200, response.text
    return client


def current_lab(client) -> np.ndarray:
    response = client.get("/api/map.lab")
    assert response.status_code == 200
    height, width = int(response.headers["X-Map-Height"]), int(response.headers["X-Map-Width"])
    return np.frombuffer(response.content, "<f4").reshape(height, width, 3)


def wait_for(client, state: str, timeout: float = 60.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = client.get("/api/status").json()
        if status["job"]["state"] == state:
            return status
        time.sleep(0.05)
    raise AssertionError(f"synthesis not {state} after {timeout} s: {status}")


# --- security --------------------------------------------------------------------------------------------
def test_token_required_on_page_and_api(studio):
    with TestClient(create_app(studio), base_url=BASE) as bare:
        assert bare.get("/api/state").status_code == 403
        assert "token" in bare.get("/api/state").json()["error"]
        assert bare.get("/").status_code == 403
        assert bare.get("/api/state", params={"token": "wrong"}).status_code == 403
        assert bare.post("/api/undo").status_code == 403
        assert bare.get("/api/state", params={"token": TOKEN}).status_code == 200
        assert bare.get("/api/state", headers={"X-Patternshop-Token": TOKEN}).status_code == 200
        assert bare.get("/api/state", headers={"Authorization": f"token {TOKEN}"}).status_code == 200
        page = bare.get("/", params={"token": TOKEN})
        assert page.status_code == 200 and 'data-testid="map-view"' in page.text
        assert "default-src 'self'" in page.headers["content-security-policy"]
        assert bare.get("/static/studio.js").status_code == 200  # static files carry no secret


def test_host_and_origin_checks(studio):
    app = create_app(studio)
    headers = {"X-Patternshop-Token": TOKEN}
    with TestClient(app, base_url="http://evil.example:8765", headers=headers) as rebinding:
        response = rebinding.get("/api/state")
        assert response.status_code == 403 and "Host" in response.json()["error"]
    for base in ("http://localhost:8765", "http://[::1]:8765", BASE):
        with TestClient(app, base_url=base, headers=headers) as local:
            assert local.get("/api/state").status_code == 200
    with TestClient(app, base_url=BASE, headers=headers) as client:
        assert client.post("/api/undo", headers={"Origin": "http://evil.example"}).status_code == 403
        assert client.get("/api/state", headers={"Origin": "http://localhost:8765"}).status_code == 403  # not the same origin
        assert client.get("/api/state", headers={"Origin": "null"}).status_code == 403
        assert client.get("/api/state", headers={"Origin": BASE}).status_code == 200


# --- opening files ---------------------------------------------------------------------------------------
def test_open_map_upload(client, tmp_path):
    source = random_map(20, 30)
    response = client.post("/api/open?name=random.tif", content=tif_bytes(source, tmp_path))
    assert response.status_code == 200, response.text
    body = response.json()
    assert (body["width"], body["height"], body["name"]) == (30, 20, "random.tif")
    np.testing.assert_allclose(current_lab(client), read_map(tmp_path / "upload-source.tif").lab)
    # an sRGB PNG opens too, with the conversion's warning passed on
    buffer = io.BytesIO()
    Image.fromarray(np.full((8, 12, 3), 128, np.uint8)).save(buffer, format="PNG")
    response = client.post("/api/open?name=grey.png", content=buffer.getvalue())
    assert response.status_code == 200 and response.json()["warning"] and "grey.png" in response.json()["warning"]
    assert client.post("/api/undo").json()["name"] == "random.tif"  # opening is undoable


def test_open_rejects_corrupt_empty_unsupported_and_large_uploads(client, tmp_path):
    response = client.post("/api/open?name=broken.tif", content=b"II*\x00garbage" * 10)
    assert response.status_code == 400
    message = response.json()["error"]
    assert message.startswith("broken.tif:") and "upload" not in message.split(":")[0] and "\n" not in message
    assert client.post("/api/open?name=empty.tif", content=b"").status_code == 400
    response = client.post("/api/open?name=notes.doc", content=b"hello")
    assert response.status_code == 400 and "open a map" in response.json()["error"]
    assert client.post("/api/open?name=map.tif&as=sketch", content=b"x").status_code == 400
    response = client.post("/api/open?name=big.tif", content=b"\0" * 300_000)
    assert response.status_code == 413 and "limit" in response.json()["error"]
    assert client.get("/api/map.lab").status_code == 400  # still no map, and the project is untouched
    assert client.get("/api/state").json()["version"] == 0


def test_new_blank_map(client):
    response = client.post("/api/new", json={"width": 40, "height": 20, "density": 0.25, "correlation": "green"})
    assert response.status_code == 200, response.text
    lab = current_lab(client)
    assert lab.shape == (20, 40, 3) and np.allclose(lab[..., 0], 75.0)
    assert client.post("/api/new", json={"width": 0}).status_code == 400


# --- the map and edits -----------------------------------------------------------------------------------
def test_map_preview_png_is_srgb_of_the_map(opened):
    response = opened.get("/api/map.png")
    assert response.status_code == 200 and response.headers["content-type"] == "image/png"
    rgb = np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))
    np.testing.assert_array_equal(rgb, LabMap(current_lab(opened)).to_srgb8())


def test_density_brush_darkens_and_lightens(opened):
    before = current_lab(opened).copy()
    stroke = {"type": "density", "centres": [[10, 10], [20, 10]], "size": 8, "hardness": 1.0, "strength": 0.5, "mode": "darken"}
    response = opened.post("/api/edit", json=stroke)
    assert response.status_code == 200 and response.json()["changed"] and response.json()["can_undo"]
    after = current_lab(opened)
    assert after[10, 10, 0] == pytest.approx(before[10, 10, 0] * 0.5, abs=1e-4)  # inside: L (1 - w)
    assert after[10, 20, 0] == pytest.approx(before[10, 20, 0] * 0.5, abs=1e-4)
    assert after[30, 40, 0] == before[30, 40, 0]  # far away: untouched
    np.testing.assert_array_equal(after[..., 1:], before[..., 1:])  # colour untouched
    opened.post("/api/edit", json={**stroke, "mode": "lighten", "strength": 1.0})
    assert current_lab(opened)[10, 20, 0] == pytest.approx(100.0)


def test_correlation_brush_paints_the_current_colour(opened):
    opened.post("/api/edit", json={"type": "correlation", "centres": [[24, 16]], "size": 10, "hardness": 0.5,
                                   "strength": 1.0, "ab": [-60, 30]})
    lab = current_lab(opened)
    np.testing.assert_allclose(lab[16, 24, 1:], (-60, 30), atol=1e-4)
    np.testing.assert_allclose(lab[0, 0, 1:], (24, -52))
    edge = lab[16, 24 + 4, 1:]  # in the soft edge: between the two colours
    assert -60 < edge[0] < 24


def test_fill_gradient_expand_and_eraser(opened):
    original = current_lab(opened).copy()
    assert opened.post("/api/edit", json={"type": "fill", "rect": [0, 0, 10, 8], "ab": [-40, 20], "density": 0.9}).status_code == 200
    lab = current_lab(opened)
    np.testing.assert_allclose(lab[:8, :10], np.broadcast_to(np.array([10.0, -40, 20], np.float32), (8, 10, 3)), atol=1e-4)
    assert lab[8, 0, 1] == 24.0 and lab[0, 10, 1] == 24.0
    flipped = opened.post("/api/edit", json={"type": "fill", "rect": [20.5, 6, 12, 2], "ab": [-40, 20]})  # corners any way
    assert flipped.json()["changed"] and np.all(current_lab(opened)[2:6, 12:21, 1] == -40)
    assert current_lab(opened)[2:6, 21, 1] == pytest.approx(24.0) and current_lab(opened)[6, 12, 1] == 24.0
    assert not opened.post("/api/edit", json={"type": "fill", "rect": [30, 2, 30, 9], "ab": [0, 0]}).json()["changed"]
    lab = current_lab(opened)
    opened.post("/api/edit", json={"type": "gradient", "start": [0, 0], "end": [48, 0], "values": [1.0, 0.0]})
    L = current_lab(opened)[..., 0]
    assert L[5, 0] < 5 and L[5, 47] > 95 and np.all(np.diff(L[20]) >= 0)
    response = opened.post("/api/edit", json={"type": "expand", "margins": [4, 2, 0, 0], "fill": [100, 0, 0]})
    assert (response.json()["width"], response.json()["height"], response.json()["offset"]) == (52, 34, [4, 2])
    # the eraser paints the opened map back, where it lies after the expansion
    opened.post("/api/edit", json={"type": "eraser", "centres": [[4 + 24, 2 + 16]], "size": 200, "hardness": 1.0, "strength": 1.0})
    lab = current_lab(opened)
    np.testing.assert_allclose(lab[2:, 4:], original, atol=1e-4)
    assert np.all(lab[:2, :, 0] == 100.0)  # the new margin: nothing to erase back to


@pytest.mark.parametrize("edit, words", [
    ({"type": "spray"}, "unknown edit type"),
    ({"type": "density", "size": 5}, "centres"),
    ({"type": "density", "centres": [[1, 2]], "size": -1}, "size"),
    ({"type": "density", "centres": [[1, 2]], "size": 5, "mode": "invert"}, "darken or lighten"),
    ({"type": "correlation", "centres": [[1, 2]], "size": 5, "ab": [300, 0]}, "[-128, 127]"),
    ({"type": "fill", "rect": [0, 0, 5, 5]}, "ab"),
    ({"type": "gradient", "start": [1, 1], "end": [1, 1]}, "same point"),
    ({"type": "expand", "margins": [0, 0, 9000, 0]}, "margin"),
    ([1, 2], "JSON object"),
])
def test_bad_edits_are_one_line_400s(opened, edit, words):
    version = opened.get("/api/state").json()["version"]
    response = opened.post("/api/edit", json=edit)
    assert response.status_code == 400 and words in response.json()["error"], response.text
    assert opened.get("/api/state").json()["version"] == version


def test_not_json_and_no_map(client):
    assert client.post("/api/edit", content=b"{nope").status_code == 400
    response = client.post("/api/edit", json={"type": "density", "centres": [[1, 1]], "size": 3})
    assert response.status_code == 400 and "no map" in response.json()["error"]
    assert client.get("/api/map.png").status_code == 400


def test_undo_redo_sixty_steps_and_persistence(opened, studio):
    maps = [current_lab(opened).copy()]
    for step in range(60):
        response = opened.post("/api/edit", json={"type": "density", "centres": [[step % 48, 16]], "size": 3,
                                                  "hardness": 1.0, "strength": 0.3})
        assert response.json()["changed"]
        maps.append(current_lab(opened).copy())
    for step in range(55):
        assert opened.post("/api/undo").status_code == 200
    np.testing.assert_array_equal(current_lab(opened), maps[5])
    for _ in range(3):
        opened.post("/api/redo")
    np.testing.assert_array_equal(current_lab(opened), maps[8])
    state = opened.get("/api/state").json()
    assert len(state["undo"]) == 8 + 1 - 1 and len(state["redo"]) == 52  # the first open is not a step
    # the folder holds the same state: reopen it as a new server would
    studio.project.close()
    again = Project(studio.project.folder)
    np.testing.assert_array_equal(again.lab, maps[8])
    assert len(again.state["redo"]) == 52
    np.testing.assert_array_equal(again.undo()["version"] and again.lab, maps[7])
    again.close()
    files = {p.name for p in (studio.project.folder / "maps").iterdir()}
    assert sum(name.startswith("map-") for name in files) == 1  # old map files are dropped


def test_history_is_limited_and_nothing_to_undo(tmp_path):
    project = Project(tmp_path / "p", history_limit=5)
    project.open_map(smooth_map().lab, "smooth.tif")
    with pytest.raises(Exception, match="nothing to undo"):
        project.undo()
    for step in range(8):
        project.edit({"type": "fill", "rect": [step, 0, step + 1, 1], "density": 1.0})
    assert len(project.state["undo"]) == 5 and len(list((tmp_path / "p" / "history").iterdir())) == 5
    project.close()


def test_summary_is_built_once_per_committed_state(tmp_path):
    """The page polls the status: the project's summary is cached until the next commit (edit, undo, settings,
    points), and then shows the change."""
    project = Project(tmp_path / "p")
    project.open_map(np.asarray(smooth_map().lab), "smooth")
    first = project.summary()
    assert project.summary()["settings"] is first["settings"]  # not rebuilt
    project.update_settings({"seed": 4})
    assert project.summary()["settings"]["seed"] == 4
    project.edit({"type": "density", "centres": [[5, 5]], "size": 4})
    summary = project.summary()
    assert summary["version"] != first["version"] and summary["undo"][-1] == "density brush (darken)"
    project.undo()
    assert project.summary()["redo"] == ["density brush (darken)"]
    project.close()


def test_second_studio_on_the_same_project_is_refused(studio):
    with pytest.raises(Exception, match="open in another"):
        Project(studio.project.folder)


def test_settings(client):
    response = client.post("/api/settings", json={"seed": 7, "points": 500, "ab": [-10, 20], "tool": "correlation"})
    assert response.status_code == 200 and response.json()["seed"] == 7
    assert client.get("/api/settings").json()["ab"] == [-10, 20]
    for bad in ({"seed": -1}, {"points": 1}, {"tool": "spray"}, {"nonsense": 1}, {"ab": [0]}):
        response = client.post("/api/settings", json=bad)
        assert response.status_code == 400, bad
    assert client.get("/api/state").json()["settings"]["points"] == 500


# --- synthesis -------------------------------------------------------------------------------------------
def test_synthesize_status_points_and_progress(opened):
    assert opened.get("/api/points.txt").status_code == 404
    response = opened.post("/api/synthesize", json={"points": 300, "seed": 3, "iterations": 20})
    assert response.status_code == 202 and response.json()["job"]["state"] in ("running", "done")
    status = wait_for(opened, "done")
    assert re.search(r"\b300 points\b", status["text"]), status["text"]
    text = opened.get("/api/points.txt")
    assert text.status_code == 200 and "domain: 1 0.666666667" in text.text
    rows = [line for line in text.text.splitlines() if line and not line.startswith("#")]
    assert len(rows) == 300
    frame = opened.get("/api/points.json", params={"since": 0}).json()
    assert frame["final"] and frame["n"] == 300 and len(frame["points"]) == 600 and frame["iteration"] == 20
    xy = np.asarray(frame["points"]).reshape(-1, 2)
    assert np.all(xy >= 0) and np.all(xy[:, 0] <= 1) and np.all(xy[:, 1] <= 2 / 3)
    unchanged = opened.get("/api/points.json", params={"since": frame["frame"]}).json()
    assert unchanged["points"] is None and unchanged["frame"] == frame["frame"]
    assert opened.get("/api/state").json()["points"]["n"] == 300
    binary = opened.get("/api/points.bin", params={"since": 0})
    meta = json.loads(binary.headers["X-Points"])
    assert meta["final"] and meta["n"] == 300 and meta["frame"] == frame["frame"] and "300 points" in meta["status"]["text"]
    np.testing.assert_allclose(np.frombuffer(binary.content, "<f4").reshape(-1, 2), xy, atol=1e-5)
    nothing = opened.get("/api/points.bin", params={"since": frame["frame"]})
    assert nothing.status_code == 204 and not nothing.content and json.loads(nothing.headers["X-Points"])["frame"] == frame["frame"]
    assert opened.get("/api/points.json", params={"since": "x"}).status_code == 400


def test_first_points_are_there_when_the_synthesis_request_is_answered(opened):
    """Progressive delivery: the answer to POST /api/synthesize already has points to show (a density-matched
    preview), long before the iterations end; then the synthesis's own frames follow with growing numbers."""
    response = opened.post("/api/synthesize", json={"points": 2000, "seed": 5, "iterations": 100000})
    assert response.status_code == 202
    binary = opened.get("/api/points.bin", params={"since": 0})
    assert binary.status_code == 200, "no points right after the synthesis request"
    meta = json.loads(binary.headers["X-Points"])
    assert not meta["final"] and meta["n"] == 2000 and meta["iteration"] < meta["total"] == 100000
    assert meta["status"]["job"]["state"] == "running" and meta["status"]["job"]["first_points_seconds"] is not None
    xy = np.frombuffer(binary.content, "<f4").reshape(-1, 2)
    assert xy.shape == (2000, 2) and np.all(xy >= 0) and np.all(xy[:, 0] <= 1) and np.all(xy[:, 1] <= 2 / 3)
    lab = current_lab(opened)  # the preview follows the density: more points in the darker half of the map
    density = 1 - lab[..., 0] / 100
    left = density[:, : lab.shape[1] // 2].sum() / density.sum()
    assert abs(np.mean(xy[:, 0] < 0.5) - left) < 0.05
    deadline = time.monotonic() + 30
    while True:  # the synthesis's own frames follow while it still runs
        later = opened.get("/api/points.bin", params={"since": meta["frame"]})
        if later.status_code == 200:
            break
        assert time.monotonic() < deadline, "no frame from the synthesis"
        time.sleep(0.05)
    assert json.loads(later.headers["X-Points"])["frame"] > meta["frame"]
    assert opened.post("/api/cancel").json()["cancelled"]


def test_an_edit_cancels_the_running_synthesis(opened):
    opened.post("/api/synthesize", json={"points": 2000, "iterations": 100000})
    deadline = time.monotonic() + 30
    while opened.get("/api/points.json", params={"since": 0}).json()["points"] is None:  # the start is published
        assert time.monotonic() < deadline
        time.sleep(0.05)
    first = opened.get("/api/points.json", params={"since": 0}).json()
    assert not first["final"] and first["n"] == 2000
    opened.post("/api/edit", json={"type": "density", "centres": [[5, 5]], "size": 4})
    status = opened.get("/api/status").json()
    assert status["job"]["state"] == "cancelled" and "map changed" in status["text"]
    opened.post("/api/synthesize", json={"points": 2000, "iterations": 100000})
    response = opened.post("/api/cancel")
    assert response.json()["cancelled"] and response.json()["status"]["job"]["state"] == "cancelled"


def read_events(lines, until: str, timeout: float = 60.0) -> list[tuple[str, dict]]:
    """(event, data) pairs from the lines of a text/event-stream response, up to the first data containing ``until``
    (an idle stream sends keep-alive lines: make EVENT_HEARTBEAT short so that the timeout is looked at)."""
    events, name, deadline = [], None, time.monotonic() + timeout
    for line in lines:
        assert time.monotonic() < deadline, f"no {until!r} after {timeout} s: {events}"
        if line.startswith("event: "):
            name = line[len("event: "):]
        elif line.startswith("data: "):
            events.append((name, json.loads(line[len("data: "):])))
            if until in line:
                return events
    raise AssertionError(f"the event stream ended before {until!r}: {events}")


def test_progress_events_stream_a_synthesis(opened, studio, monkeypatch):
    """GET /api/events (Server-Sent Events) needs the token (as a query parameter) like every API call, sends
    the status at once, then the frames and the status as the synthesis runs, the final points before "done"."""
    monkeypatch.setattr(server, "EVENT_HEARTBEAT", 0.5)
    with TestClient(create_app(studio), base_url=BASE) as bare:
        with bare.stream("GET", "/api/events") as response:
            assert response.status_code == 403
        with bare.stream("GET", "/api/events", params={"token": TOKEN}, headers={"Origin": "http://evil.example"}) as response:
            assert response.status_code == 403
        with bare.stream("GET", "/api/events", params={"token": TOKEN}) as response:
            assert response.status_code == 200 and response.headers["content-type"].startswith("text/event-stream")
            lines = response.iter_lines()
            first = read_events(lines, '"state": "idle"')
            assert first == [("status", studio.status())]
            assert bare.post("/api/synthesize", params={"token": TOKEN},
                             json={"points": 300, "seed": 3, "iterations": 40}).status_code == 202
            events = read_events(lines, '"state": "done"')
    points = [data for name, data in events if name == "points"]
    assert points[0]["preview"] and not points[0]["final"] and points[0]["n"] == 300
    assert [p["frame"] for p in points] == sorted({p["frame"] for p in points})
    assert points[-1]["final"] and points[-1]["n"] == 300 and points[-1]["iteration"] == 40
    assert events[-1][0] == "status" and events[-1][1]["job"]["n"] == 300
    assert re.search(r"\b300 points\b", events[-1][1]["text"]), events[-1][1]["text"]
    assert events.index(("points", points[-1])) < len(events) - 1  # the final points come before "done"
    assert any(name == "status" and data["job"]["state"] == "running" for name, data in events)


def test_idle_event_stream_keeps_alive_and_ends_when_the_server_stops(studio, monkeypatch):
    """An idle stream sends keep-alive comments (writing is how a gone client is noticed) and ends once the
    server is stopping (uvicorn waits for open responses when it stops)."""
    import asyncio

    monkeypatch.setattr(server, "EVENT_HEARTBEAT", 0.5)

    async def collect() -> list[str]:
        chunks = []
        async for chunk in server._event_stream(studio):
            chunks.append(chunk)
            if chunk.startswith(":"):
                studio.stopping = lambda: True
        return chunks

    chunks = asyncio.run(asyncio.wait_for(collect(), 30))
    assert chunks[0].startswith("retry:") and [c.split("\n")[0] for c in chunks[1:]] == ["event: status", ": keep-alive"]


def points_of(client) -> np.ndarray:
    text = client.get("/api/points.txt").text
    return np.array([[float(v) for v in line.split()] for line in text.splitlines() if line and not line.startswith("#")])


def test_a_local_edit_remakes_only_its_region(client):
    """After a synthesis, an edit in a corner re-makes the points there (at the new density, with no stacked
    points) and leaves every point far from it exactly where it was; a full synthesis would move them all."""
    client.post("/api/new", json={"width": 128, "height": 96, "density": 0.4, "correlation": "blue"})
    client.post("/api/settings", json={"points_per_ink": 8000.0})  # 8000 x 0.75 x 0.4 = 2400 points
    client.post("/api/synthesize", json={})
    assert wait_for(client, "done")["job"]["local"] is None  # the first synthesis is a full one
    before = points_of(client)
    assert len(before) == 2400
    rect = [8, 8, 40, 40]  # map pixels; darker: density 0.4 -> 0.8
    client.post("/api/edit", json={"type": "fill", "rect": rect, "density": 0.8})
    client.post("/api/synthesize", json={})
    status = wait_for(client, "done")
    assert status["job"]["local"] is not None and "re-made locally" in status["text"], status
    after = points_of(client)
    side = 128
    expected = 8000 * (128 * 96 / side**2) * (0.4 + (0.8 - 0.4) * 32 * 32 / (128 * 96))
    assert abs(len(after) - expected) < 0.01 * expected
    spacing = np.sqrt(0.75 / len(after))  # map units
    far = lambda xy: (xy[:, 0] * side > 40 + 12 * spacing * side) | (xy[:, 1] * side > 40 + 12 * spacing * side)
    np.testing.assert_array_equal(np.sort(before[far(before)], axis=0), np.sort(after[far(after)], axis=0))
    inside = np.all((after * side >= 8) & (after * side <= 40), axis=1)
    assert abs(inside.sum() - len(after) * 0.8 * 32 * 32 / ((0.4 * (128 * 96 - 32 * 32)) + 0.8 * 32 * 32)) < 0.08 * inside.sum()
    from scipy.spatial import cKDTree

    distance, _ = cKDTree(after).query(after[inside], k=2)
    local_spacing = np.sqrt(2 / (np.sqrt(3) * len(after) * 0.8 / (0.4 * 0.75 + 0.4 * 32 * 32 / side**2)))
    assert distance[:, 1].min() > 0.3 * local_spacing  # blue noise: no stacked or near points in the new region
    # another seed (or a large change) is a full synthesis again
    client.post("/api/synthesize", json={"seed": 7})
    assert wait_for(client, "done")["job"]["local"] is None


def test_local_update_plan():
    """plan_local_update: None (a full synthesis) without a change, with another seed, count setting or size, or a
    change too large; else kept points outside the window, about the new count, new points only near the change."""
    from patternshop.studio.incremental import Base, plan_local_update

    rng = np.random.default_rng(0)
    lab = np.zeros((64, 96, 3), np.float32)
    lab[..., 0] = 50.0
    xy = rng.random((3000, 2)) * (1.0, 64 / 96)
    base = Base(lab, xy, 0, ("ink", 1.0))
    edited = lab.copy()
    edited[10:14, 70:74, 0] = 20.0  # darker
    assert plan_local_update(base, lab, 3000, 0, ("ink", 1.0)) is None
    assert plan_local_update(base, edited, 3000, 1, ("ink", 1.0)) is None
    assert plan_local_update(base, edited, 3000, 0, ("points", 3000)) is None
    assert plan_local_update(base, edited[:-1], 3000, 0, ("ink", 1.0)) is None
    wide = lab.copy()
    wide[:, :84, 0] = 20.0  # the window: the whole map
    assert plan_local_update(base, wide, 3000, 0, ("ink", 1.0)) is None
    plan = plan_local_update(base, edited, 3030, 0, ("ink", 1.0))
    y0, y1, x0, x1 = plan.box
    assert y0 <= 10 and y1 >= 14 and x0 <= 70 and x1 >= 74 and plan.window_share < 0.3
    assert abs(plan.n - 3030) <= 40 and plan.drawn > 0  # kept: a random base, its count in the region varies
    outside = ~np.all((xy * 96 >= (x0, y0)) & (xy * 96 < (x1, y1)), axis=1)
    np.testing.assert_array_equal(plan.fixed, xy[outside])
    new = plan.start[-plan.drawn :] * 96
    assert np.all(np.hypot(new[:, 0] - 72, new[:, 1] - 12) < 2 + 6 * np.sqrt(64 * 96 / 3030) * 2)
    window_xy = plan.to_window(plan.start)
    np.testing.assert_allclose(plan.to_map(window_xy), plan.start, atol=1e-12)
    moved = plan.merge(window_xy + 1e-4)  # only the band's points take the run's positions
    assert np.array_equal(moved[: len(plan.fixed)], plan.fixed)
    changed = np.any(moved[len(plan.fixed) :] != plan.start, axis=1)
    np.testing.assert_array_equal(changed, plan.refined)


def test_synthesis_restarts_from_saved_points(tmp_path):
    """A restarted studio whose saved points belong to the current map re-makes an edit locally too."""
    project = Project(tmp_path / "p")
    project.open_map(np.asarray(api_uniform(96, 0.4).lab), "m")
    project.update_settings({"points_per_ink": 4000.0})
    first = Studio(project, token=TOKEN)
    first.synthesizer.start()
    first.synthesizer.wait(60)
    assert first.synthesizer.status()["state"] == "done"
    project.close()
    project = Project(tmp_path / "p")
    second = Studio(project, token=TOKEN)
    assert second.synthesizer.base is not None
    project.edit({"type": "density", "centres": [[20, 20]], "size": 8, "strength": 0.5})
    second.synthesizer.start()
    second.synthesizer.wait(60)
    assert second.synthesizer.status()["state"] == "done" and second.synthesizer.status()["local"] is not None
    project.close()


def api_uniform(side: int, density: float) -> LabMap:
    from patternshop import api

    return api.uniform_map(side, density=density, correlation="blue")


def test_bad_synthesis_requests(opened, client):
    for body in ({"points": 1}, {"seed": -3}, {"points": "many"}, {"colour": 1}, {"points": 10**9}):
        response = opened.post("/api/synthesize", json=body)
        assert response.status_code == 400, body
    assert "memory" in opened.post("/api/synthesize", json={"points": 10**9}).json()["error"]
    opened.post("/api/new", json={"width": 8, "density": 0.0})
    response = opened.post("/api/synthesize", json={})
    assert response.status_code == 400 and "white" in response.json()["error"]


# --- palette and exports ---------------------------------------------------------------------------------
def test_palette_endpoints(client):
    info = client.get("/api/palette").json()
    assert info["presets"]["blue"] == [24.0, -52.0] and info["picture"]["side"] > 0
    picture = client.get("/api/palette.png")
    assert picture.status_code == 200
    assert Image.open(io.BytesIO(picture.content)).size == (info["picture"]["width"], info["picture"]["height"])
    example = client.get("/api/palette/example", params={"a": 24, "b": -52, "n": 200}).json()
    assert example["nearest_preset"] == "blue" and example["populated"]
    xy = np.asarray(example["points"]).reshape(-1, 2)
    assert 120 < len(xy) < 300 and np.all((xy >= 0) & (xy <= 1))
    assert client.get("/api/palette/example", params={"a": 500, "b": 0}).status_code == 400
    assert client.get("/api/palette/example", params={"a": "x", "b": 0}).status_code == 400


def test_exports(opened, tmp_path):
    assert opened.get("/api/export/points.txt").status_code == 404
    tif = opened.get("/api/export/map.tif")
    assert tif.status_code == 200 and 'filename="smooth.map.tif"' in tif.headers["content-disposition"]
    (tmp_path / "back.tif").write_bytes(tif.content)
    np.testing.assert_allclose(read_map(tmp_path / "back.tif").lab, current_lab(opened), atol=0.01)
    assert opened.get("/api/export/map8.tif").status_code == 200
    assert opened.get("/api/export/map.png").content[:4] == b"\x89PNG"
    assert opened.get("/api/export/nothing.bin").status_code == 404
    opened.post("/api/synthesize", json={"points": 100, "iterations": 5})
    wait_for(opened, "done")
    for name, magic in (("points.txt", b"# patternshop"), ("points.csv", b"x,y"), ("points.npy", b"\x93NUMPY"),
                        ("points.svg", b"<?xml"), ("points.png", b"\x89PNG")):
        response = opened.get(f"/api/export/{name}")
        assert response.status_code == 200 and response.content.startswith(magic), name
    download = opened.get("/api/points.txt", params={"download": 1})
    assert "attachment" in download.headers["content-disposition"]


# --- the edit arithmetic the page repeats ----------------------------------------------------------------
def test_stroke_weight_profile():
    weight, box = stroke_weight((20, 20), np.array([[10.0, 10.0]]), size=10, hardness=0.4, strength=0.8)
    y0, _, x0, _ = box
    assert weight[10 - y0, 10 - x0] == pytest.approx(0.8)  # centre: full strength
    assert weight[10 - y0, 15 - x0] == 0.0  # pixel centre (15.5, 10.5): beyond the radius 5
    r = np.hypot(13.5 - 10.0, 10.5 - 10.0)  # pixel (row 10, column 13) lies in the soft edge, from 0.4 x 5 to 5
    t = (5 - r) / (5 - 2.0)
    assert weight[10 - y0, 13 - x0] == pytest.approx(0.8 * t * t * (3 - 2 * t))
    assert stroke_weight((20, 20), np.array([[-50.0, -50.0]]), 10, 0.5, 1.0) is None
    lab = smooth_map().lab
    assert np.array_equal(apply_edit(lab, {"type": "density", "centres": [[-50, -50]], "size": 4}).lab, lab)


# --- kill -9 of a real server ----------------------------------------------------------------------------
def _start_server(project: Path, *args: str) -> tuple[subprocess.Popen, str]:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    process = subprocess.Popen([sys.executable, "-m", "patternshop", "studio", "--no-browser", "--port", "0",
                                "--project", str(project), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, cwd=ROOT, env=env)
    lines = []
    while len(lines) < 5:  # a point file prints a line before the URL
        lines.append(process.stdout.readline())
        match = re.search(r"(http://\S+)", lines[-1])
        if match is not None:
            return process, match.group(1)
        if not lines[-1]:
            break
    process.kill()
    raise AssertionError(f"no URL printed: {lines!r} {process.stderr.read()}")


def _call(url: str, path: str, body: dict | None = None) -> dict:
    base, token = url.split("/?token=")
    request = urllib.request.Request(f"{base}{path}", data=None if body is None else json.dumps(body).encode(),
                                     headers={"X-Patternshop-Token": token, "Content-Type": "application/json"},
                                     method="GET" if body is None else "POST")
    deadline = time.monotonic() + 20
    while True:
        try:
            with urllib.request.urlopen(request, timeout=20) as response:
                data = response.read()
                return json.loads(data) if response.headers.get_content_type() == "application/json" else {"bytes": data}
        except (ConnectionError, urllib.error.URLError) as exc:
            if isinstance(exc, urllib.error.HTTPError) or time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def _call_once(url: str, path: str, body: dict) -> None:
    """One try, no answer expected (the server is about to die)."""
    base, token = url.split("/?token=")
    request = urllib.request.Request(f"{base}{path}", data=json.dumps(body).encode(), method="POST",
                                     headers={"X-Patternshop-Token": token, "Content-Type": "application/json"})
    try:
        urllib.request.urlopen(request, timeout=20).read()
    except (OSError, urllib.error.URLError, http.client.HTTPException):  # the server died mid-answer
        pass


def test_kill_9_keeps_every_acknowledged_edit(tmp_path):
    project = tmp_path / "project"
    process, url = _start_server(project, str(ROOT / "examples" / "logo.tif"))
    strokes = [{"type": "density", "centres": [[40 + 30 * i, 60], [60 + 30 * i, 80]], "size": 30, "hardness": 0.5,
                "strength": 0.7, "mode": "darken"} for i in range(4)]
    try:
        expected = [np.array(read_map(ROOT / "examples" / "logo.tif").lab)]
        for stroke in strokes[:3]:
            assert _call(url, "/api/edit", stroke)["changed"]  # acknowledged
            expected.append(apply_edit(expected[-1], stroke).lab)
        # the fourth edit is in flight when the server dies
        threading.Thread(target=_call_once, args=(url, "/api/edit", strokes[3]), daemon=True).start()
        time.sleep(0.01)
        process.send_signal(signal.SIGKILL)
        process.wait(10)
    finally:
        process.kill()
        process.communicate()
    expected.append(apply_edit(expected[-1], strokes[3]).lab)
    process, url = _start_server(project)  # no file: the project as it was
    try:
        state = _call(url, "/api/state")
        lab = np.frombuffer(_call(url, "/api/map.lab")["bytes"], "<f4").reshape(state["height"], state["width"], 3)
        steps = len(state["undo"])
        assert steps in (3, 4), state["undo"]  # the three acknowledged edits, and the fourth only if it was committed
        np.testing.assert_array_equal(lab, expected[steps])
        assert state["name"] == "logo.tif"
        _call(url, "/api/undo", {})
        state = _call(url, "/api/state")
        lab = np.frombuffer(_call(url, "/api/map.lab")["bytes"], "<f4").reshape(state["height"], state["width"], 3)
        np.testing.assert_array_equal(lab, expected[steps - 1])
    finally:
        process.terminate()
        process.communicate(timeout=20)


# --- the command and the package -------------------------------------------------------------------------
def test_studio_command_errors_are_one_line(tmp_path, capsys):
    from helpers import run_cli

    status, _, err = run_cli(["studio", str(tmp_path / "missing.tif"), "--no-browser", "--project", str(tmp_path / "p")], capsys)
    assert status == 2 and "missing.tif" in err and len(err.strip().splitlines()) == 1
    status, _, err = run_cli(["studio", "--port", "70000"], capsys)
    assert status == 2 and "port" in err
    (tmp_path / "bad.tif").write_bytes(b"II*\x00nonsense")
    status, _, err = run_cli(["studio", str(tmp_path / "bad.tif"), "--no-browser", "--project", str(tmp_path / "p")], capsys)
    assert status == 2 and "bad.tif" in err


def test_page_files_ship_as_package_data():
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "patternshop.studio" in config["packages"]
    assert config["package-data"]["patternshop.studio"] == ["static/*"]
    static = ROOT / "patternshop" / "studio" / "static"
    assert {p.name for p in static.iterdir()} >= {"index.html", "studio.js", "studio.css"}
    page = (static / "index.html").read_text()
    for testid in ("map-view", "points-view", "palette", "tool-density", "tool-correlation", "tool-gradient", "undo",
                   "redo", "synthesize", "status", "export-points", "export-map", "open-file"):
        assert f'data-testid="{testid}"' in page, testid
    for text in (page, (static / "studio.js").read_text(), (static / "studio.css").read_text()):
        assert not re.search(r"(src|href)=\"?https?://|url\(https?:|fetch\(\"https?:", text)  # nothing from outside


def test_open_a_photo_and_a_point_file(client, tmp_path):
    buffer = io.BytesIO()
    Image.fromarray(np.tile(np.linspace(0, 255, 40).astype(np.uint8), (20, 1))).save(buffer, format="PNG")
    response = client.post("/api/open?name=photo.png&as=photo&gamma=1&correlation=green", content=buffer.getvalue())
    assert response.status_code == 200, response.text
    lab = current_lab(client)
    assert lab.shape == (20, 40, 3) and lab[0, 0, 0] < 5 and lab[0, -1, 0] > 95  # black is full ink, white none
    np.testing.assert_allclose(lab[0, 0, 1:], client.get("/api/palette").json()["presets"]["green"], atol=1e-3)
    assert client.post("/api/open?name=photo.png&as=photo&gamma=x", content=buffer.getvalue()).status_code == 400
    assert client.post("/api/open?name=notes.doc&as=photo", content=b"x").status_code == 400
    # a point file: the network infers its map
    points = (ROOT / "examples" / "logo_points.txt").read_text()
    response = client.post("/api/open?name=logo_points.txt&points_per_ink=20000", content=points.encode())
    assert response.status_code == 200, response.text
    assert response.json()["name"] == "logo_points.txt" and response.json()["width"] == 256
    response = client.post("/api/open?name=bad.txt", content=b"0.1 0.2\nabc def\n")
    assert response.status_code == 400 and response.json()["error"].startswith("bad.txt:2")


def test_studio_opens_a_point_file_given_on_the_command_line(tmp_path):
    process, url = _start_server(tmp_path / "project", str(ROOT / "examples" / "logo_points.txt"))
    try:
        state = _call(url, "/api/state")
        assert state["name"] == "logo_points.txt" and (state["width"], state["height"]) == (256, 171)
    finally:
        process.terminate()
        process.communicate(timeout=20)


def test_lasso_and_magic_wand_fills(opened):
    response = opened.post("/api/edit", json={"type": "fill", "polygon": [[10, 4], [30, 4], [30, 20], [10, 20]], "ab": [-40, 20]})
    assert response.status_code == 200 and response.json()["undo"][-1] == "lasso fill"
    lab = current_lab(opened)
    assert np.all(lab[5:19, 11:29, 1] == -40) and lab[2, 20, 1] == 24 and lab[25, 20, 1] == 24 and lab[10, 5, 1] == 24
    # the wand takes the connected pixels of similar colour: the lasso's square, not the rest of the map
    opened.post("/api/edit", json={"type": "fill", "seed": [20, 10], "tolerance": 30, "density": 1.0})
    lab = current_lab(opened)
    inside = lab[..., 1] == -40
    assert np.all(lab[inside, 0] == 0.0) and np.all(lab[~inside, 0] > 0)
    assert opened.get("/api/state").json()["undo"][-1] == "similar-colour fill"
    # not contiguous: every pixel of similar colour (L varies from 30 to 80 left to right; this tolerance takes about half)
    opened.post("/api/edit", json={"type": "fill", "seed": [47, 31], "tolerance": 25, "contiguous": False, "ab": [0, 0]})
    lab = current_lab(opened)
    assert lab[31, 47, 1] == 0 and lab[0, 47, 1] == 0 and lab[31, 0, 1] == 24
    for bad in ({"type": "fill", "polygon": [[0, 0], [1, 1]], "ab": [0, 0]}, {"type": "fill", "seed": [500, 1], "ab": [0, 0]},
                {"type": "fill", "ab": [0, 0]}):
        assert opened.post("/api/edit", json=bad).status_code == 400, bad
    assert opened.post("/api/settings", json={"tool": "wand", "tolerance": 12, "overlay": 0.3}).status_code == 200
