"""The studio's web server: a Starlette application (the page and its HTTP API) served by uvicorn.

Why Starlette and not FastAPI: the API is a dozen routes taking JSON or raw uploads, validated by the
edit and settings checkers the tests call directly; FastAPI would add pydantic models on top, and its
import costs about 0.55 s against Starlette's 0.16 s (measured on the 2-core development machine, 3 runs
each), a third of the 1.5 s server-start target.

Security, as Jupyter does it (:class:`Guard`):

* the server binds 127.0.0.1 unless told otherwise;
* a random token, printed in the URL, is required by the page (``/``) and by every ``/api/`` call, as the
  ``token`` query parameter or the ``X-Patternshop-Token`` header (``Authorization: token T`` works too);
* the ``Host`` header must name the loopback interface (or the ``--host`` given): a DNS-rebinding page
  whose name resolves to 127.0.0.1 gets 403;
* an ``Origin`` header, when present, must be the server's own origin: cross-site requests get 403;
* uploads are limited in size (413 with a message); no path from the page reaches the file system
  (files come in as uploads and go out as downloads; the project folder is the server's own).

Errors are JSON ``{"error": "one line"}`` with a 4xx status; the project is untouched by a failed request.

Progress is pushed by Server-Sent Events (``GET /api/events``, :func:`events`): the synthesizer's worker thread
bumps a :class:`Changes` counter, which wakes each stream's ``asyncio.Event`` through
``loop.call_soon_threadsafe``; the stream then sends what changed (a ``points`` event: a newer frame is
available from ``points.bin``; a ``status`` event: the status line). Streams end when the client goes or the
server stops (:attr:`Studio.stopping`; uvicorn waits for open responses before it exits).
"""

from __future__ import annotations

import asyncio
import hmac
import io
import json
import secrets
import tempfile
import threading
import urllib.parse
from pathlib import Path
from typing import Any, AsyncIterator, Callable

import numpy as np
from starlette.applications import Starlette
from starlette.background import BackgroundTask
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from patternshop.studio.jobs import Synthesizer
from patternshop.studio.project import Project
from synthesis.errors import PatternshopError

STATIC_DIR = Path(__file__).resolve().parent / "static"
TOKEN_HEADER = "x-patternshop-token"
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
DEFAULT_MAX_UPLOAD_BYTES = 100 * 1024 * 1024
MAP_SUFFIXES = (".tif", ".tiff", ".png", ".jpg", ".jpeg")
PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".webp", ".bmp")
POINT_SUFFIXES = (".txt", ".csv", ".xy", ".pts", ".npy")
EXPORTS = {  # name -> (media type, what it needs)
    "map.tif": ("image/tiff", "map"), "map8.tif": ("image/tiff", "map"), "map.png": ("image/png", "map"),
    "points.txt": ("text/plain", "points"), "points.csv": ("text/csv", "points"),
    "points.npy": ("application/octet-stream", "points"), "points.svg": ("image/svg+xml", "points"),
    "points.png": ("image/png", "points"),
}
EVENT_HEARTBEAT = 15.0  # seconds between keep-alive comments on an idle event stream (proxies; a gone client)
EVENT_STOP_CHECK = 0.5  # seconds between an idle event stream's looks at Studio.stopping
CONTENT_SECURITY_POLICY = ("default-src 'self'; img-src 'self' blob: data:; style-src 'self'; script-src 'self'; "
                           "connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'")


def error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": " ".join(str(message).split())}, status_code=status)


def _split_host(host: str) -> str:
    """The name in a Host header value (``[::1]:8000`` -> ``::1``, ``localhost:8000`` -> ``localhost``)."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


class Guard:
    """ASGI middleware: Host and Origin checks on every request, the token on the page and the API."""

    def __init__(self, app: Any, token: str, allowed_hosts: tuple[str, ...] = LOOPBACK_HOSTS) -> None:
        self.app = app
        self.token = token
        self.allowed_hosts = tuple(h.lower() for h in allowed_hosts)

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {key.decode("latin-1").lower(): value.decode("latin-1") for key, value in scope["headers"]}
        host = headers.get("host", "")
        problem = None
        if _split_host(host) not in self.allowed_hosts:
            problem = f"Host {host!r} is not allowed: open the studio at the URL 'patternshop studio' printed"
        elif "origin" in headers and headers["origin"].lower().rstrip("/") != f"http://{host.lower()}":
            problem = f"cross-origin request from {headers['origin']!r} refused"
        elif (scope["path"] == "/" or scope["path"].startswith("/api/")) and not self._has_token(scope, headers):
            problem = ("missing or wrong token: open the studio at the URL 'patternshop studio' printed "
                       "(it carries ?token=...)")
        if problem is None:
            await self.app(scope, receive, send)
            return
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008})
            return
        await error(403, problem)(scope, receive, send)

    def _has_token(self, scope: dict, headers: dict[str, str]) -> bool:
        given = headers.get(TOKEN_HEADER)
        if given is None:
            authorization = headers.get("authorization", "")
            for prefix in ("token ", "bearer "):
                if authorization.lower().startswith(prefix):
                    given = authorization[len(prefix) :].strip()
        if given is None:
            query = urllib.parse.parse_qs(scope.get("query_string", b"").decode("latin-1"))
            given = (query.get("token") or [None])[0]
        return given is not None and hmac.compare_digest(given.encode(), self.token.encode())


class Changes:
    """A change counter that any thread bumps and event streams wait on without blocking the event loop."""

    def __init__(self) -> None:
        self.number = 0
        self._lock = threading.Lock()
        self._waiters: list[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = []

    def bump(self) -> None:
        """Count a change and wake every waiting stream (thread-safe)."""
        with self._lock:
            self.number += 1
            waiters, self._waiters = self._waiters, []
        for loop, event in waiters:
            try:
                loop.call_soon_threadsafe(event.set)
            except RuntimeError:  # that stream's loop is closed
                pass

    async def wait(self, seen: int, timeout: float) -> bool:
        """Wait until the counter differs from ``seen`` (True) or ``timeout`` seconds pass (False)."""
        event = asyncio.Event()
        waiter = (asyncio.get_running_loop(), event)
        with self._lock:
            if self.number != seen:
                return True
            self._waiters.append(waiter)
        try:
            await asyncio.wait_for(event.wait(), timeout)
            return True
        except asyncio.TimeoutError:
            return False
        finally:
            with self._lock:
                if waiter in self._waiters:
                    self._waiters.remove(waiter)


class Studio:
    """What the server holds: the project, the synthesizer, limits, and the palette (loaded once)."""

    def __init__(self, project: Project, token: str | None = None, max_upload_bytes: int = DEFAULT_MAX_UPLOAD_BYTES,
                 max_memory_gb: float = 4.0) -> None:
        self.project = project
        self.token = token or secrets.token_urlsafe(24)
        self.max_upload_bytes = max_upload_bytes
        self.max_memory_gb = max_memory_gb
        self.changes = Changes()  # bumped by the synthesizer: wakes the event streams
        self.synthesizer = Synthesizer(project, max_memory_gb, on_change=self.changes.bump)
        self.stopping: Callable[[], bool] = lambda: False  # serve(): True once the server is asked to stop
        self._palette_lock = threading.Lock()
        self._palette_png: bytes | None = None
        self._map_png: tuple[int, bytes] | None = None  # (version, sRGB PNG) of the current map
        self.activity: str | None = None  # what a long request (inference, a photo) is doing, for the status line
        self.warm_up_on_load = False  # serve(): warm the synthesiser up once the page has loaded

    # --- the palette -------------------------------------------------------------------------------------
    def palette(self) -> Any:
        from synthesis.palette import load_palette

        return load_palette()

    def palette_png(self) -> bytes:
        from synthesis.palette_image import draw_palette

        with self._palette_lock:
            if self._palette_png is None:
                with tempfile.TemporaryDirectory(dir=self.project.folder) as folder:
                    path = Path(folder) / "palette.png"
                    draw_palette(self.palette(), path)
                    self._palette_png = path.read_bytes()
            return self._palette_png

    def map_png(self) -> tuple[bytes, int]:
        """(the current map as an 8-bit sRGB PNG, its version), encoded once per version (the page and the
        map.png export ask for it after every edit; the array of a version never changes)."""
        from PIL import Image

        from synthesis.labmap import LabMap

        lab, version = self.project.current()
        cached = self._map_png
        if cached is None or cached[0] != version:
            buffer = io.BytesIO()
            Image.fromarray(LabMap(lab).to_srgb8()).save(buffer, format="PNG")  # as synthesis.mapio.write_preview
            cached = self._map_png = (version, buffer.getvalue())
        return cached[1], version

    # --- status ------------------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        summary = self.project.summary()
        job = self.synthesizer.status()
        state = job["state"]
        if self.activity:
            text = f"{self.activity}…"
        elif state == "running":
            text = f"Synthesizing: iteration {job['iteration']} of {job['total']} (n = {job['n']})"
        elif state == "done":
            text = f"Done: {job['n']} points in {job['seconds']:.1f} s"
            if job["local"]:
                text += f" (re-made locally: {job['local']['window_share']:.0%} of the map)"
            if job["version"] != summary["version"]:
                text += " (the map has changed since)"
        elif state == "cancelled":
            text = f"Synthesis cancelled: {job['message']}"
        elif state == "error":
            text = f"Synthesis failed: {job['message']}"
        elif summary["points"]:
            text = f"Ready. Last synthesis: {summary['points']['n']} points"
        elif summary["width"]:
            text = f"Ready: {summary['name'] or 'map'}, {summary['width']} x {summary['height']} px"
        else:
            text = "Ready: open a map"
        return {"text": text, "job": job, "version": summary["version"], "can_undo": summary["can_undo"],
                "can_redo": summary["can_redo"]}


# --- helpers -----------------------------------------------------------------------------------------------
async def _json_body(request: Request, limit: int = 1 << 24) -> Any:
    body = await request.body()
    if len(body) > limit:
        raise PatternshopError(f"request body over {limit} bytes")
    if not body:
        return {}
    try:
        return json.loads(body)
    except ValueError as exc:
        raise PatternshopError(f"the request body is not JSON ({exc})") from None


class TooLarge(Exception):
    pass


async def _upload(request: Request, limit: int) -> bytes:
    length = request.headers.get("content-length")
    if length is not None and length.isdigit() and int(length) > limit:
        raise TooLarge
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise TooLarge
        chunks.append(chunk)
    return b"".join(chunks)


def _int_param(request: Request, name: str, default: int) -> int:
    text = request.query_params.get(name)
    if text is None:
        return default
    try:
        return int(text)
    except ValueError:
        raise PatternshopError(f"{name} must be an integer, got {text!r}") from None


def _float_param(request: Request, name: str) -> float:
    text = request.query_params.get(name)
    try:
        value = float(text) if text is not None else None
    except ValueError:
        value = None
    if value is None or not np.isfinite(value):
        raise PatternshopError(f"{name} must be a number, got {text!r}")
    return value


def _handle(function: Any) -> Any:
    """An endpoint that turns user errors into 400 (404 for a missing resource) with a one-line message."""

    async def endpoint(request: Request) -> Response:
        try:
            return await function(request)
        except TooLarge:
            limit = request.app.state.studio.max_upload_bytes
            return error(413, f"the upload is larger than the limit of {limit / 1e6:.3g} MB "
                              "(restart the studio with a higher --max-upload-mb)")
        except FileNotFoundError as exc:
            return error(404, str(exc))
        except PatternshopError as exc:
            return error(400, str(exc))
        except MemoryError:
            return error(400, "out of memory: use a smaller map or fewer points")
        except OSError as exc:  # the project folder (disk full, permissions): the page says so and stays usable
            return error(500, f"the studio could not use its project folder: {exc.strerror or exc}")

    return endpoint


# --- endpoints ---------------------------------------------------------------------------------------------
async def index(request: Request) -> Response:
    html = (STATIC_DIR / "index.html").read_text(encoding="utf-8")
    return HTMLResponse(html, headers={"Content-Security-Policy": CONTENT_SECURITY_POLICY, "Cache-Control": "no-store",
                                       "Referrer-Policy": "no-referrer"})


async def get_state(request: Request) -> Response:
    studio: Studio = request.app.state.studio
    return JSONResponse({**studio.project.summary(), "status": studio.status()})


async def get_status(request: Request) -> Response:
    return JSONResponse(request.app.state.studio.status())


async def map_png(request: Request) -> Response:
    data, version = await run_in_threadpool(request.app.state.studio.map_png)
    return Response(data, media_type="image/png",
                    headers={"X-Map-Version": str(version), "Cache-Control": "no-store"})


async def map_lab(request: Request) -> Response:
    lab, version = request.app.state.studio.project.current()
    return Response(np.ascontiguousarray(lab, "<f4").tobytes(), media_type="application/octet-stream",
                    headers={"X-Map-Width": str(lab.shape[1]), "X-Map-Height": str(lab.shape[0]),
                             "X-Map-Version": str(version), "Cache-Control": "no-store"})


def _open_options(request: Request, name: str, suffix: str) -> tuple[str, dict[str, Any]]:
    """What an upload is (``as``: map, photo or points; default from the suffix) and its options."""
    kind = request.query_params.get("as") or ("points" if suffix in POINT_SUFFIXES else "map")
    allowed = {"map": MAP_SUFFIXES, "photo": PHOTO_SUFFIXES, "points": POINT_SUFFIXES}
    if kind not in allowed:
        raise PatternshopError(f"as must be map, photo or points, got {kind!r}")
    if suffix not in allowed[kind]:
        hint = {"map": "open a map: CIELAB .tif/.tiff, or an sRGB .png/.jpg (channel PNGs: join them into a .tif "
                       "with 'patternshop join' first), or a point file (.txt, .csv, .npy)",
                "photo": "a photo is a .png, .jpg, .tif, .webp or .bmp",
                "points": "a point file is .txt, .csv, .xy, .pts or .npy"}[kind]
        raise PatternshopError(f"{name or 'the file'}: {hint}")
    options: dict[str, Any] = {}
    if kind == "photo":
        params = request.query_params
        options["gamma"] = _float_param(request, "gamma") if "gamma" in params else 1.0
        options["invert"] = params.get("invert", "").lower() in ("1", "true", "yes")
        if "levels" in params:
            try:
                options["levels"] = tuple(float(v) for v in params["levels"].split(","))
            except ValueError:
                raise PatternshopError(f"levels must be 'black,white', got {params['levels']!r}") from None
        options["correlation"] = params.get("correlation") or request.app.state.studio.project.settings["ab"]
    elif kind == "points" and "points_per_ink" in request.query_params:
        options["points_per_ink"] = _float_param(request, "points_per_ink")
    return kind, options


async def open_file(request: Request) -> Response:
    """Body: the file's bytes; ``name``: its file name (its suffix says the format); ``as``: ``map``
    (default), ``photo`` (a photo becomes a map, as ``patternshop from-image``: ``gamma``, ``invert``,
    ``levels``, ``correlation``) or ``points`` (default for point files: the network infers the map;
    ``points_per_ink``)."""
    from patternshop import api
    from synthesis import resources
    from synthesis.mapio import map_size, read_map

    studio: Studio = request.app.state.studio
    name = Path(request.query_params.get("name", "")).name
    suffix = Path(name).suffix.lower()
    kind, options = _open_options(request, name, suffix)
    data = await _upload(request, studio.max_upload_bytes)
    if not data:
        raise PatternshopError(f"{name}: the upload is empty")

    def read() -> dict[str, Any]:
        import warnings

        with tempfile.TemporaryDirectory(dir=studio.project.folder) as folder:
            path = Path(folder) / f"upload{suffix}"
            path.write_bytes(data)
            try:
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    if kind == "map":
                        width, height = map_size(path)
                        needed = resources.map_bytes(width * height)
                        if needed > studio.max_memory_gb * 1e9:
                            raise PatternshopError(f"a {width} x {height} px map needs about {needed / 1e9:.3g} GB, "
                                                   f"over the limit of {studio.max_memory_gb:g} GB (--max-memory-gb)")
                        lab_map = read_map(path)
                    elif kind == "photo":
                        studio.activity = f"Making a map of the photo {name}"
                        lab_map = api.from_image(path, **options)
                    else:
                        needed = resources.point_file_bytes(len(data), npy=suffix == ".npy")
                        if needed > studio.max_memory_gb * 1e9:
                            raise PatternshopError(f"reading it needs about {needed / 1e9:.3g} GB, over the limit of "
                                                   f"{studio.max_memory_gb:g} GB (--max-memory-gb)")
                        studio.activity = f"Inferring the map of {name} with the network (a few seconds)"
                        lab_map = api.infer(path, **options).lab_map
            except PatternshopError as exc:  # name the upload, not the temporary file
                text = str(exc).replace(str(path), name)
                raise PatternshopError(text if text.startswith(name) else f"{name}: {text}") from None
            finally:
                studio.activity = None
        message = "; ".join(" ".join(str(w.message).replace(str(path), name).split()) for w in caught)
        studio.synthesizer.cancel("a map was opened")
        summary = studio.project.open_map(np.asarray(lab_map.lab), name)
        return {**summary, "warning": message or None}

    return JSONResponse(await run_in_threadpool(read))


async def new_map(request: Request) -> Response:
    """JSON ``{width, height, density, correlation}``: a blank map of one density and correlation."""
    from patternshop import api

    studio: Studio = request.app.state.studio
    body = await _json_body(request)
    width, height = body.get("width", 512), body.get("height", body.get("width", 512))
    for key, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 4096:
            raise PatternshopError(f"{key} must be an integer from 1 to 4096, got {value!r}")
    lab_map = api.uniform_map(width, height, density=body.get("density", 0.3), correlation=body.get("correlation", "blue"))
    studio.synthesizer.cancel("a new map was made")
    return JSONResponse(await run_in_threadpool(studio.project.open_map, np.asarray(lab_map.lab), "blank map"))


async def apply_edit(request: Request) -> Response:
    studio: Studio = request.app.state.studio
    edit = await _json_body(request)
    summary = await run_in_threadpool(studio.project.edit, edit)
    if summary["changed"]:
        studio.synthesizer.cancel("the map changed")
    return JSONResponse(summary)


async def undo(request: Request) -> Response:
    studio: Studio = request.app.state.studio
    summary = await run_in_threadpool(studio.project.undo)
    studio.synthesizer.cancel("the map changed")
    return JSONResponse(summary)


async def redo(request: Request) -> Response:
    studio: Studio = request.app.state.studio
    summary = await run_in_threadpool(studio.project.redo)
    studio.synthesizer.cancel("the map changed")
    return JSONResponse(summary)


async def settings(request: Request) -> Response:
    studio: Studio = request.app.state.studio
    if request.method == "GET":
        return JSONResponse(studio.project.settings)
    changes = await _json_body(request)
    return JSONResponse(await run_in_threadpool(studio.project.update_settings, changes))


async def synthesize(request: Request) -> Response:
    """JSON ``{points, seed, iterations}`` (each optional: the settings' values)."""
    studio: Studio = request.app.state.studio
    body = await _json_body(request)
    if not isinstance(body, dict):
        raise PatternshopError("the body is a JSON object {points, seed, iterations}")
    unknown = set(body) - {"points", "seed", "iterations"}
    if unknown:
        raise PatternshopError(f"unknown field(s) {', '.join(sorted(unknown))}; fields: points, seed, iterations")
    await run_in_threadpool(studio.synthesizer.start, body.get("points"), body.get("seed"), body.get("iterations"))
    return JSONResponse(studio.status(), status_code=202)


async def cancel(request: Request) -> Response:
    studio: Studio = request.app.state.studio
    return JSONResponse({"cancelled": studio.synthesizer.cancel("cancelled by the user"), "status": studio.status()})


async def points_txt(request: Request) -> Response:
    studio: Studio = request.app.state.studio
    path = studio.project.points_path()
    if path is None or not path.exists():
        return error(404, "no points yet: synthesize first (POST /api/synthesize)")
    data = await run_in_threadpool(path.read_bytes)
    headers = {"Cache-Control": "no-store"}
    if request.query_params.get("download"):
        headers["Content-Disposition"] = f'attachment; filename="{_stem(studio)}.points.txt"'
    return Response(data, media_type="text/plain; charset=utf-8", headers=headers)


async def points_json(request: Request) -> Response:
    """The newest frame of points if newer than ``since`` (else ``points: null``): while a synthesis runs,
    the points as they form; after it, the final points."""
    studio: Studio = request.app.state.studio
    since = _int_param(request, "since", 0)
    frame = studio.synthesizer.frame_since(since)
    if frame is None:
        latest = studio.synthesizer.latest_frame()
        return JSONResponse({"frame": latest.number if latest else 0, "points": None, "status": studio.status()})

    def encode() -> dict[str, Any]:
        return {**_frame_meta(studio, frame), "points": np.round(frame.xy, 5).ravel().tolist()}

    return JSONResponse(await run_in_threadpool(encode))


def _frame_fields(frame: Any) -> dict[str, Any]:
    """What the ``points`` event says about a frame: its number, job, map version, iteration, total, final,
    preview, n, domain."""
    return {"frame": frame.number, "job": frame.job, "version": frame.version, "iteration": frame.iteration,
            "total": frame.total, "final": frame.final, "preview": frame.preview, "n": int(len(frame.xy)),
            "domain": list(frame.domain)}


def _frame_meta(studio: Studio, frame: Any) -> dict[str, Any]:
    """What points.json and points.bin say about a frame besides its points."""
    return {**_frame_fields(frame), "status": studio.status()}


async def points_bin(request: Request) -> Response:
    """As ``points.json``, binary: the body is the frame's points as float32 little-endian x, y pairs (204 and
    no body when nothing is newer than ``since``); the header ``X-Points`` carries the rest as JSON (ASCII):
    frame, job, version, iteration, total, final, preview, n, domain, status. About 100x cheaper to serve than JSON
    (which matters: the synthesis shares the interpreter with the server)."""
    studio: Studio = request.app.state.studio
    since = _int_param(request, "since", 0)
    # the page asks for points since 0 while it loads: warm the synthesiser up 0.5 s later (after the page's
    # other requests, not to delay them)
    warm = None
    if since == 0 and studio.warm_up_on_load:
        timer = threading.Timer(0.5, studio.synthesizer.warm_up)
        timer.daemon = True
        warm = BackgroundTask(timer.start)
    frame = studio.synthesizer.frame_since(since)
    if frame is None:
        latest = studio.synthesizer.latest_frame()
        meta = {"frame": latest.number if latest else 0, "n": None, "status": studio.status()}
        return Response(status_code=204, headers={"X-Points": json.dumps(meta), "Cache-Control": "no-store"},
                        background=warm)
    return Response(np.ascontiguousarray(frame.xy, "<f4").tobytes(), media_type="application/octet-stream",
                    headers={"X-Points": json.dumps(_frame_meta(studio, frame)), "Cache-Control": "no-store"},
                    background=warm)


async def events(request: Request) -> Response:
    """Server-Sent Events (``text/event-stream``) for as long as the page keeps it open: ``points`` (a frame's
    fields as points.bin's header gives them, without the status) when a newer frame of points is available,
    then ``status`` (as ``GET /api/status``) when the status line or the job changes; both at once on connect.
    The token comes as the ``token`` query parameter (EventSource cannot set headers)."""
    return StreamingResponse(_event_stream(request.app.state.studio), media_type="text/event-stream",
                             headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})


def _sse(event: str, data: Any) -> str:
    return f"event: {event}\ndata: {json.dumps(data)}\n\n"


async def _event_stream(studio: Studio) -> AsyncIterator[str]:
    """The events of :func:`events`; waits on :attr:`Studio.changes` (never blocks the event loop), sends a
    keep-alive comment every :data:`EVENT_HEARTBEAT` s when idle and ends when :attr:`Studio.stopping` says so.
    A client that goes ends it at once (Starlette cancels it on uvicorn's disconnect message; under an ASGI 2.4
    server, at the next write: the keep-alive bounds that)."""
    yield "retry: 1000\n\n"  # the browser reconnects after 1 s if the stream breaks
    seen, frame_sent, status_sent, idle = -1, 0, None, 0.0
    while not studio.stopping():
        if not await studio.changes.wait(seen, EVENT_STOP_CHECK):
            idle += EVENT_STOP_CHECK
            if idle >= EVENT_HEARTBEAT:
                idle = 0.0
                yield ": keep-alive\n\n"
            continue
        idle, seen = 0.0, studio.changes.number
        frame = studio.synthesizer.latest_frame()
        if frame is not None and frame.number != frame_sent:  # before the status: "done" follows the final points
            frame_sent = frame.number
            yield _sse("points", _frame_fields(frame))
        status = studio.status()
        key = json.dumps({**status, "job": {k: v for k, v in status["job"].items() if k != "seconds"}})
        if key != status_sent:
            status_sent = key
            yield _sse("status", status)


async def palette_info(request: Request) -> Response:
    from synthesis.palette_image import MARGIN

    studio: Studio = request.app.state.studio
    palette = await run_in_threadpool(studio.palette)
    grid, cell = 9, 112  # draw_palette's defaults
    side = grid * cell
    return JSONResponse({"presets": {name: list(ab) for name, ab in palette.preset_ab().items()},
                         "picture": {"width": side + 2 * MARGIN, "height": side + 2 * MARGIN, "left": MARGIN,
                                     "top": MARGIN, "side": side, "a": [-128, 127], "b": [127, -128]}})


async def palette_png(request: Request) -> Response:
    studio: Studio = request.app.state.studio
    return Response(await run_in_threadpool(studio.palette_png), media_type="image/png",
                    headers={"Cache-Control": "private, max-age=3600"})


async def palette_example(request: Request) -> Response:
    """The pattern of the colour (a, b): the palette's nearest exemplar, cropped to about ``n`` points."""
    from synthesis.palette import ab_to_latent

    studio: Studio = request.app.state.studio
    a, b = _float_param(request, "a"), _float_param(request, "b")
    if not (-128 <= a <= 127 and -128 <= b <= 127):
        raise PatternshopError(f"a and b must be in [-128, 127], got {a:g}, {b:g}")
    n = _int_param(request, "n", 300)
    if not 10 <= n <= 1024:
        raise PatternshopError(f"n must be from 10 to 1024, got {n}")
    palette = await run_in_threadpool(studio.palette)
    z = ab_to_latent(np.array([a, b]))
    distance = np.linalg.norm(palette.exemplar_z - z, axis=1)
    nearest = int(np.argmin(distance))
    points = palette.exemplar_points[nearest]
    window = float(np.sqrt(n / points.shape[0]))
    inside = points[np.all(points < window, axis=1)] / window
    return JSONResponse({"a": a, "b": b, "nearest_preset": palette.nearest_preset(a, b),
                         "populated": bool(palette.is_populated(z[None])[0]), "exemplar": nearest,
                         "exemplar_distance": round(float(distance[nearest]), 4),
                         "points": np.round(inside, 4).ravel().tolist()})


def _stem(studio: Studio) -> str:
    name = studio.project.state.get("name") or "map"
    stem = Path(name).stem if "." in name else name
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in stem) or "map"


async def export(request: Request) -> Response:
    """Downloads written by the CLI's writers: map.tif (16-bit), map8.tif, map.png (sRGB preview, as
    ``write_preview`` writes it), points.txt/.csv/.npy/.svg/.png."""
    from synthesis.labmap import LabMap
    from synthesis.mapio import write_map
    from synthesis.points import read_points, write_points
    from synthesis.render import render_png, write_svg

    studio: Studio = request.app.state.studio
    name = request.path_params["name"]
    if name not in EXPORTS:
        return error(404, f"no export {name!r}; exports: {', '.join(EXPORTS)}")
    media, needs = EXPORTS[name]
    lab, _ = studio.project.current()
    points_path = studio.project.points_path()
    if needs == "points" and (points_path is None or not points_path.exists()):
        return error(404, "no points yet: synthesize first")

    def write() -> bytes:
        if name == "map.png":  # the sRGB preview the page shows, encoded once per map version
            return studio.map_png()[0]
        with tempfile.TemporaryDirectory(dir=studio.project.folder) as folder:
            target = Path(folder) / name
            if name == "map.tif":
                write_map(LabMap(lab), target, bits=16)
            elif name == "map8.tif":
                write_map(LabMap(lab), target, bits=8)
            else:
                points = read_points(points_path)
                if name == "points.svg":
                    write_svg(points, target)
                elif name == "points.png":
                    render_png(points, target)
                else:
                    write_points(points, target)
            return target.read_bytes()

    data = await run_in_threadpool(write)
    filename = f"{_stem(studio)}.{name}"
    return Response(data, media_type=media, headers={"Content-Disposition": f'attachment; filename="{filename}"',
                                                      "Cache-Control": "no-store"})


def create_app(studio: Studio, allowed_hosts: tuple[str, ...] = LOOPBACK_HOSTS) -> Any:
    """The ASGI application: the Starlette app behind :class:`Guard`. ``app.state.studio`` is ``studio``."""
    routes = [
        Route("/", index),
        Route("/api/state", _handle(get_state)),
        Route("/api/status", _handle(get_status)),
        Route("/api/map.png", _handle(map_png)),
        Route("/api/map.lab", _handle(map_lab)),
        Route("/api/open", _handle(open_file), methods=["POST"]),
        Route("/api/new", _handle(new_map), methods=["POST"]),
        Route("/api/edit", _handle(apply_edit), methods=["POST"]),
        Route("/api/undo", _handle(undo), methods=["POST"]),
        Route("/api/redo", _handle(redo), methods=["POST"]),
        Route("/api/settings", _handle(settings), methods=["GET", "POST"]),
        Route("/api/synthesize", _handle(synthesize), methods=["POST"]),
        Route("/api/cancel", _handle(cancel), methods=["POST"]),
        Route("/api/points.txt", _handle(points_txt)),
        Route("/api/points.json", _handle(points_json)),
        Route("/api/points.bin", _handle(points_bin)),
        Route("/api/events", _handle(events)),
        Route("/api/palette", _handle(palette_info)),
        Route("/api/palette.png", _handle(palette_png)),
        Route("/api/palette/example", _handle(palette_example)),
        Route("/api/export/{name}", _handle(export)),
        Mount("/static", StaticFiles(directory=STATIC_DIR), name="static"),
    ]
    app = Starlette(routes=routes)
    app.state.studio = studio
    guarded = Guard(app, studio.token, allowed_hosts)
    guarded.state = app.state  # type: ignore[attr-defined] - tests reach the studio as app.state.studio
    return guarded


def studio_url(host: str, port: int, token: str) -> str:
    shown = f"[{host}]" if ":" in host else host
    return f"http://{shown}:{port}/?token={token}"


def _bind(host: str, port: int, tries: int) -> Any:
    """A listening socket on ``host``: ``port``, or the next free one of ``tries`` (port 0: any free port)."""
    import socket

    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    last: OSError | None = None
    for candidate in ([0] if port == 0 else range(port, port + tries)):
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, candidate))
        except OSError as exc:
            sock.close()
            last = exc
            continue
        sock.listen(128)
        sock.set_inheritable(True)
        return sock
    raise PatternshopError(f"cannot listen on {host} port {port}" + (f" to {port + tries - 1}" if tries > 1 else "")
                           + f" ({last.strerror if last else 'no port'}); choose another with --port")


def serve(project: Project, *, host: str = "127.0.0.1", port: int = 8765, port_tries: int = 20,
          open_browser: bool = True, max_upload_bytes: int = DEFAULT_MAX_UPLOAD_BYTES, max_memory_gb: float = 4.0,
          token: str | None = None, announce: Any = print) -> None:
    """Serve the studio of ``project`` until interrupted (Ctrl+C); prints the URL with its token first."""
    import webbrowser

    import uvicorn

    studio = Studio(project, token=token, max_upload_bytes=max_upload_bytes, max_memory_gb=max_memory_gb)
    allowed = LOOPBACK_HOSTS if host in LOOPBACK_HOSTS else (*LOOPBACK_HOSTS, host)
    app = create_app(studio, allowed)
    sock = _bind(host, port, port_tries if port else 1)
    bound_port = sock.getsockname()[1]
    url = studio_url("127.0.0.1" if host in ("127.0.0.1", "0.0.0.0") else host, bound_port, studio.token)
    announce(f"Patternshop Studio: {url}")
    announce(f"project: {project.folder} (Ctrl+C stops the server; every edit is already saved)")
    if open_browser:
        threading.Timer(0.3, webbrowser.open, [url]).start()
    studio.warm_up_on_load = True  # the page's first points request starts the warm-up (see points_bin)
    studio.synthesizer.warm_up(delay=3.0)  # or 3 s from now: the first synthesis then starts at once
    config = uvicorn.Config(app, log_level="warning", lifespan="off", access_log=False)
    server = uvicorn.Server(config)
    studio.stopping = lambda: server.should_exit  # ends the event streams, which uvicorn waits for when it stops
    try:
        server.run(sockets=[sock])
    finally:
        studio.synthesizer.cancel("the server stopped")
        sock.close()
