"""The studio's project folder: the current map, the opened map, the edit history and the settings.

Layout of a project folder::

    state.json                 what is current: map and opened-map files, undo/redo steps, settings, points
    maps/map-NNNNNN.npy        the current map, (H, W, 3) float32 CIELAB (one file; the name changes per edit)
    maps/origin-NNNNNN.npy     the map as opened (the eraser paints it back); older ones while steps need them
    history/step-NNNNNN.npz    one per undo/redo step: the changed box before and after (or whole maps)
    points.txt                 the last finished synthesis
    .lock                      held (flock) while a studio has the folder open

**Nothing acknowledged is lost.** An edit writes its step file and the new map file (each atomically:
temporary file, then rename), then ``state.json`` (atomically): that rename is the commit. Only then is
the edit acknowledged to the page. A server killed at any moment (``kill -9``) restarts on the last
committed state; files no state refers to are removed when the folder is opened again.
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import os
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np

from patternshop.studio.tools import apply_edit
from synthesis.atomic import atomic_path, atomic_write_text
from synthesis.errors import PatternshopError

STATE_NAME = "state.json"
FORMAT_VERSION = 1
HISTORY_LIMIT = 100  # undo steps kept (the issue asks for at least 50)
MAX_SEED = 2**32 - 1
TOOLS = ("density", "correlation", "eraser", "fill", "lasso", "wand", "gradient", "pan")
DEFAULT_SETTINGS: dict[str, Any] = {
    "points": None,  # None: points_per_ink x mean density
    "points_per_ink": 50_000.0,
    "seed": 0,
    "auto": False,
    "ab": [24.0, -52.0],  # the current correlation (blue noise in the shipped palette)
    "tool": "density",
    "mode": "darken",
    "size": 40.0,
    "hardness": 0.5,
    "strength": 0.5,
    "gradient": [0.8, 0.1],
    "fill_density": None,
    "tolerance": 10.0,  # the magic wand's colour distance (CIELAB)
    "overlay": 0.0,  # opacity of the map under the points view
    "view": None,  # [zoom, x, y] of the page's shared view
}


def default_project_dir() -> Path:
    """Where a project lives without ``--project``: the user's data directory, ``patternshop/studio``."""
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
        return base / "Patternshop" / "studio"
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Application Support" / "Patternshop" / "studio"
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "patternshop" / "studio"


# --- settings ----------------------------------------------------------------------------------------------
def _bad(key: str, value: Any, what: str) -> PatternshopError:
    return PatternshopError(f"setting {key} must be {what}, got {value!r}")


def _finite(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


def check_settings(changes: Any) -> dict[str, Any]:
    """Validated settings changes (a JSON object of known keys).

    Raises:
        PatternshopError: an unknown key or a bad value, named.
    """
    if not isinstance(changes, dict):
        raise PatternshopError("settings are a JSON object")
    checked: dict[str, Any] = {}
    for key, value in changes.items():
        if key not in DEFAULT_SETTINGS:
            raise PatternshopError(f"unknown setting {key!r}; settings: {', '.join(DEFAULT_SETTINGS)}")
        if key == "points":
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 2):
                raise _bad(key, value, "an integer >= 2 or null (from the ink)")
        elif key == "points_per_ink":
            if not _finite(value) or value <= 0:
                raise _bad(key, value, "a number > 0")
        elif key == "seed":
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_SEED:
                raise _bad(key, value, f"an integer from 0 to {MAX_SEED}")
        elif key == "auto":
            if not isinstance(value, bool):
                raise _bad(key, value, "true or false")
        elif key == "ab":
            if not (isinstance(value, list) and len(value) == 2 and all(_finite(v) and -128 <= v <= 127 for v in value)):
                raise _bad(key, value, "[a, b] with a, b in [-128, 127]")
        elif key == "tool":
            if value not in TOOLS:
                raise _bad(key, value, f"one of {', '.join(TOOLS)}")
        elif key == "mode":
            if value not in ("darken", "lighten"):
                raise _bad(key, value, "darken or lighten")
        elif key == "size":
            if not _finite(value) or not 0.5 <= value <= 4096:
                raise _bad(key, value, "a number of pixels in [0.5, 4096]")
        elif key in ("hardness", "strength"):
            if not _finite(value) or not 0 <= value <= 1:
                raise _bad(key, value, "a number in [0, 1]")
        elif key == "gradient":
            if not (isinstance(value, list) and len(value) == 2 and all(_finite(v) and 0 <= v <= 1 for v in value)):
                raise _bad(key, value, "[start density, end density] in [0, 1]")
        elif key == "fill_density":
            if value is not None and (not _finite(value) or not 0 <= value <= 1):
                raise _bad(key, value, "a density in [0, 1] or null (colour only)")
        elif key == "tolerance":
            if not _finite(value) or not 0 <= value <= 400:
                raise _bad(key, value, "a CIELAB distance in [0, 400]")
        elif key == "overlay":
            if not _finite(value) or not 0 <= value <= 1:
                raise _bad(key, value, "an opacity in [0, 1]")
        elif key == "view":
            if value is not None and not (isinstance(value, list) and len(value) == 3 and all(_finite(v) for v in value)):
                raise _bad(key, value, "[zoom, x, y] or null")
        checked[key] = value
    return checked


# --- files -------------------------------------------------------------------------------------------------
def _save_array(path: Path, array: np.ndarray) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        np.save(handle, np.ascontiguousarray(array, np.float32))


def _load_map_array(path: Path) -> np.ndarray:
    try:
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise PatternshopError(f"{path}: project map unreadable ({exc})") from exc
    if array.ndim != 3 or array.shape[2] != 3 or array.dtype != np.float32:
        raise PatternshopError(f"{path}: not a project map (shape {array.shape}, {array.dtype})")
    return array


class Project:
    """A project folder opened for editing; every method is thread-safe (one lock).

    Args:
        folder: created if missing.
        history_limit: undo steps kept (older ones are forgotten).

    Raises:
        PatternshopError: the folder is open in another studio, or its state is unreadable.
    """

    def __init__(self, folder: str | os.PathLike, history_limit: int = HISTORY_LIMIT) -> None:
        self.folder = Path(folder).expanduser().resolve()
        self.history_limit = history_limit
        self.lock = threading.RLock()
        for sub in ("", "maps", "history"):
            try:
                (self.folder / sub).mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise PatternshopError(f"{self.folder}: cannot create the project folder ({exc.strerror or exc})") from exc
        self._lock_handle = self._acquire()
        self.state = self._load_state()
        self.lab: np.ndarray | None = None
        self.origin: np.ndarray | None = None
        self._summary: dict[str, Any] | None = None  # summary() of the committed state, until the next commit
        if self.state["map"]:
            self.lab = _load_map_array(self.folder / self.state["map"])
            self.origin = _load_map_array(self.folder / self.state["origin"])
        self._collect_garbage()

    # --- opening and closing ---------------------------------------------------------------------------
    def _acquire(self):  # noqa: ANN202 - an open file
        handle = open(self.folder / ".lock", "a+")  # noqa: SIM115 - held until close()
        try:
            import fcntl

            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except ImportError:  # Windows: no flock; one studio per folder is then the user's care
            pass
        except OSError:
            handle.close()
            raise PatternshopError(f"{self.folder}: this project is open in another Patternshop Studio "
                                   "(close it, or choose another folder with --project)") from None
        return handle

    def close(self) -> None:
        """Release the folder (another studio may open it)."""
        with contextlib.suppress(OSError):
            self._lock_handle.close()

    def _load_state(self) -> dict[str, Any]:
        path = self.folder / STATE_NAME
        fresh = {"format": FORMAT_VERSION, "counter": 0, "version": 0, "map": None, "origin": None, "offset": [0, 0],
                 "name": None, "undo": [], "redo": [], "settings": copy.deepcopy(DEFAULT_SETTINGS), "points": None}
        if not path.exists():
            return fresh
        try:
            state = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise PatternshopError(f"{path}: project state unreadable ({exc}); move the folder away or choose "
                                   "another with --project") from exc
        if not isinstance(state, dict) or state.get("format") != FORMAT_VERSION:
            raise PatternshopError(f"{path}: not a Patternshop Studio project of format {FORMAT_VERSION}")
        fresh.update(state)
        fresh["settings"] = {**copy.deepcopy(DEFAULT_SETTINGS), **state.get("settings", {})}
        return fresh

    def _referenced(self, state: dict[str, Any]) -> set[str]:
        names = {state["map"], state["origin"]}
        if state["points"]:
            names.add(state["points"]["file"])
        for step in state["undo"] + state["redo"]:
            names |= {step["file"], step["origin_before"], step["origin_after"]}
        return {name for name in names if name}

    def _collect_garbage(self) -> None:
        """Remove map, origin and step files no state refers to (left by a crash, or dropped from history)."""
        keep = self._referenced(self.state)
        for sub, pattern in (("maps", "map-*.npy"), ("maps", "origin-*.npy"), ("history", "step-*.npz")):
            for path in (self.folder / sub).glob(pattern):
                if f"{sub}/{path.name}" not in keep:
                    with contextlib.suppress(OSError):
                        path.unlink()

    def _commit(self, state: dict[str, Any]) -> None:
        """Write ``state`` (the commit point), then adopt it and drop files it no longer refers to."""
        atomic_write_text(self.folder / STATE_NAME, json.dumps(state, indent=1))
        self.state = state
        self._summary = None
        self._collect_garbage()

    # --- queries ---------------------------------------------------------------------------------------
    @property
    def has_map(self) -> bool:
        return self.lab is not None

    @property
    def version(self) -> int:
        """Changes with every edit, undo, redo and open (the page knows whether its copy is current)."""
        return int(self.state["version"])

    @property
    def settings(self) -> dict[str, Any]:
        return copy.deepcopy(self.state["settings"])

    def summary(self) -> dict[str, Any]:
        """The JSON-ready state the page shows: map size, version, history, settings, last points (built once per
        committed state: the page polls it; callers must not change the nested values)."""
        with self.lock:
            if self._summary is None:
                self._summary = self._build_summary()
            return dict(self._summary)

    def _build_summary(self) -> dict[str, Any]:
        state = self.state
        height, width = (self.lab.shape[:2] if self.lab is not None else (0, 0))
        side = max(width, height, 1)
        return {
            "version": self.version, "name": state["name"], "width": width, "height": height,
            "domain": [width / side, height / side], "offset": list(state["offset"]),
            "can_undo": bool(state["undo"]), "can_redo": bool(state["redo"]),
            "undo": [step["label"] for step in state["undo"]], "redo": [step["label"] for step in state["redo"]][::-1],
            "settings": self.settings, "points": copy.deepcopy(state["points"]),
        }

    def current(self) -> tuple[np.ndarray, int]:
        """(the current map, its version); the array is never changed in place (edits make new ones)."""
        with self.lock:
            self._require_map()
            return self.lab, self.version

    def _require_map(self) -> None:
        if self.lab is None:
            raise PatternshopError("no map is open: open a map file first")

    # --- changes ---------------------------------------------------------------------------------------
    def _next(self, state: dict[str, Any]) -> int:
        state["counter"] += 1
        return state["counter"]

    def open_map(self, lab: np.ndarray, name: str) -> dict[str, Any]:
        """Make ``lab`` the current and the opened map; undoable when a map was open."""
        lab = np.ascontiguousarray(lab, np.float32)
        with self.lock:
            state = copy.deepcopy(self.state)
            number = self._next(state)
            origin_name = f"maps/origin-{number:06d}.npy"
            _save_array(self.folder / origin_name, lab)
            if self.lab is not None:
                step_name = f"history/step-{number:06d}.npz"
                self._save_step(step_name, {"kind": "full", "before": self.lab, "after": lab})
                state["undo"].append({"id": number, "label": f"open {name}", "file": step_name,
                                      "origin_before": state["origin"], "origin_after": origin_name,
                                      "offset_before": state["offset"], "offset_after": [0, 0],
                                      "name_before": state["name"], "name_after": name})
                state["redo"] = []
            self._adopt(state, number, lab, origin_name, [0, 0], name)
            self.origin = lab
            return self.summary()

    def _save_step(self, name: str, data: dict[str, Any]) -> None:
        with atomic_path(self.folder / name) as tmp, open(tmp, "wb") as handle:
            np.savez(handle, **{key: np.asarray(value) for key, value in data.items()})

    def _adopt(self, state: dict[str, Any], number: int, lab: np.ndarray, origin_name: str, offset: list[int],
               name: str | None) -> None:
        """Write the new current map, then commit ``state`` pointing at it (history trimmed to the limit)."""
        map_name = f"maps/map-{number:06d}.npy"
        _save_array(self.folder / map_name, lab)
        state.update(version=number, map=map_name, origin=origin_name, offset=list(offset), name=name)
        del state["undo"][: max(0, len(state["undo"]) - self.history_limit)]
        self._commit(state)
        self.lab = lab
        self._summary = None  # it shows the map's size

    def edit(self, edit: Any) -> dict[str, Any]:
        """Apply an edit (:func:`patternshop.studio.tools.apply_edit`) and record it; returns :meth:`summary`
        with ``changed`` (False when the edit changed no pixel: nothing is recorded)."""
        with self.lock:
            self._require_map()
            result = apply_edit(self.lab, edit, self.origin, tuple(self.state["offset"]))
            if result.lab.shape == self.lab.shape:
                changed = np.any(result.lab != self.lab, axis=2)
                if not changed.any() and list(result.offset) == list(self.state["offset"]):
                    return {**self.summary(), "changed": False}
                rows, cols = np.flatnonzero(changed.any(axis=1)), np.flatnonzero(changed.any(axis=0))
                y0, y1, x0, x1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
                data = {"kind": "patch", "box": [y0, y1, x0, x1], "before": self.lab[y0:y1, x0:x1],
                        "after": result.lab[y0:y1, x0:x1]}
            else:
                data = {"kind": "full", "before": self.lab, "after": result.lab}
            state = copy.deepcopy(self.state)
            number = self._next(state)
            step_name = f"history/step-{number:06d}.npz"
            self._save_step(step_name, data)
            state["undo"].append({"id": number, "label": result.label, "file": step_name,
                                  "origin_before": state["origin"], "origin_after": state["origin"],
                                  "offset_before": state["offset"], "offset_after": list(result.offset),
                                  "name_before": state["name"], "name_after": state["name"]})
            state["redo"] = []
            self._adopt(state, number, result.lab, state["origin"], list(result.offset), state["name"])
            return {**self.summary(), "changed": True}

    def _step(self, undo: bool) -> dict[str, Any]:
        with self.lock:
            state = copy.deepcopy(self.state)
            source, target = ("undo", "redo") if undo else ("redo", "undo")
            if not state[source]:
                raise PatternshopError(f"nothing to {source}")
            step = state[source].pop()
            side = "before" if undo else "after"
            try:
                with np.load(self.folder / step["file"], allow_pickle=False) as data:
                    kind = str(data["kind"])
                    values = np.asarray(data[side], np.float32)
                    box = data["box"].tolist() if kind == "patch" else None
            except (OSError, KeyError, ValueError) as exc:
                raise PatternshopError(f"{step['file']}: history step unreadable ({exc})") from exc
            if kind == "patch":
                y0, y1, x0, x1 = box
                lab = self.lab.copy()
                lab[y0:y1, x0:x1] = values
            else:
                lab = values
            state[target].append(step)
            number = self._next(state)
            origin_name, previous_origin = step[f"origin_{side}"], self.state["origin"]
            self._adopt(state, number, lab, origin_name, step[f"offset_{side}"], step[f"name_{side}"])
            if origin_name != previous_origin:
                self.origin = _load_map_array(self.folder / origin_name)
            return {**self.summary(), "label": step["label"]}

    def undo(self) -> dict[str, Any]:
        """Undo the last edit (or open); returns :meth:`summary` and ``label``."""
        return self._step(undo=True)

    def redo(self) -> dict[str, Any]:
        """Redo the last undone edit; returns :meth:`summary` and ``label``."""
        return self._step(undo=False)

    def update_settings(self, changes: Any) -> dict[str, Any]:
        """Merge validated ``changes`` into the settings and save them; returns the settings."""
        checked = check_settings(changes)
        with self.lock:
            state = copy.deepcopy(self.state)
            state["settings"].update(checked)
            self._commit(state)
            return self.settings

    def save_points(self, points: Any, version: int, report: dict[str, Any]) -> None:
        """Keep a finished synthesis (a :class:`~synthesis.points.PointSet` of the map ``version``) as points.txt."""
        from synthesis.points import write_points

        with self.lock:
            write_points(points, self.folder / "points.txt")
            state = copy.deepcopy(self.state)
            state["points"] = {"file": "points.txt", "n": len(points), "version": version, **report}
            self._commit(state)

    def points_path(self) -> Path | None:
        """The file of the last finished synthesis, or None."""
        with self.lock:
            info = self.state["points"]
            return self.folder / info["file"] if info else None
