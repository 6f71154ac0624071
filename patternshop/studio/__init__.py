"""Patternshop Studio: a local browser editor for maps (``patternshop studio``).

* :mod:`patternshop.studio.tools` — the map edits the page applies (brushes, fill, gradient, expansion,
  eraser), pure numpy on (H, W, 3) CIELAB arrays; ``static/studio.js`` repeats the brush arithmetic so
  strokes repaint in the page before the server has them.
* :mod:`patternshop.studio.project` — the project folder: the current map, the map it was opened from,
  the undo/redo history and the settings, persisted atomically after every edit.
* :mod:`patternshop.studio.jobs` — synthesis in a worker thread, cancellable, with progressive points.
* :mod:`patternshop.studio.server` — the Starlette application (HTTP API, token, Host/Origin checks) and
  :func:`~patternshop.studio.server.serve` (uvicorn on 127.0.0.1).

docs/studio.md documents the command and the HTTP API.
"""
