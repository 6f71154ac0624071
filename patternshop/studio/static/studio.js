// Patternshop Studio: the page. Plain JavaScript, no build step, nothing fetched from outside the server.
//
// The map is held here as the server's float32 CIELAB array (GET /api/map.lab). Brush strokes repaint it at
// once with the same arithmetic as patternshop/studio/tools.py (stroke weight = strength x max over stamps of
// a smoothstep falloff; darken L(1-w), lighten L+w(100-L), correlation ab+w(target-ab)), then go to the server
// as one edit; other edits, undo and redo fetch the map again. Both views share one zoom and pan.
"use strict";

const TOKEN = new URLSearchParams(location.search).get("token") || "";
const D65 = [0.3127 / 0.3290, 1.0, (1.0 - 0.3127 - 0.3290) / 0.3290];
const XYZ_TO_SRGB = [[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]];

const S = {
  map: null,          // {width, height, lab: Float32Array, version, image: ImageData, canvas: offscreen canvas}
  view: {zoom: 1, x: 0, y: 0},
  settings: {},
  presets: {},
  picture: null,      // palette picture geometry
  points: null,       // {xy: Float64Array (flat), n, domain, final, version}
  frame: 0,           // newest points frame shown
  stroke: null,       // the brush stroke being painted
  drag: null,         // a pan, rectangle or gradient drag
  queue: Promise.resolve(),
  polling: false,
  events: null,       // the EventSource of GET /api/events; null: none (then progress is polled)
  eventTasks: Promise.resolve(),  // what the events asked for, done in their order
  autoTimer: null,
  settingsTimer: null,
  pendingSettings: {},
  space: false,
  hoverRequest: 0,
  cursor: null,       // last cursor position in map pixels, for the brush outline
};

const $ = (id) => document.getElementById(id);

// --- the server ---------------------------------------------------------------------------------------------
async function api(path, options = {}) {
  const init = {method: options.method || "GET", headers: {"X-Patternshop-Token": TOKEN}};
  if (options.json !== undefined) {
    init.body = JSON.stringify(options.json);
    init.headers["Content-Type"] = "application/json";
  } else if (options.body !== undefined) {
    init.body = options.body;
    init.headers["Content-Type"] = "application/octet-stream";
  }
  const response = await fetch(path, init);
  if (!response.ok) {
    let message = `${response.status} ${response.statusText}`;
    try { message = (await response.json()).error || message; } catch (e) { /* not JSON */ }
    throw new Error(message);
  }
  if (options.raw) return response;
  return response.json();
}

function withToken(path) {
  return `${path}${path.includes("?") ? "&" : "?"}token=${encodeURIComponent(TOKEN)}`;
}

function setStatus(text, isError = false) {
  const status = $("status");
  status.textContent = text;
  status.classList.toggle("error", isError);
}

function fail(error) {
  setStatus(`Error: ${error.message || error}`, true);
}

// Server calls that change the map run one after another, in the order they were made.
function enqueue(task) {
  const run = S.queue.then(task);
  S.queue = run.catch(() => {});
  return run;
}

// --- colour -------------------------------------------------------------------------------------------------
function labInverse(v) { return v > 24.0 / 116.0 ? v * v * v : (v - 16.0 / 116.0) / (841.0 / 108.0); }

function linearToSrgb8(lin) {
  const s = lin <= 0.0031308 ? lin * 12.92 : 1.055 * Math.pow(Math.max(lin, 0.0031308), 1.0 / 2.4) - 0.055;
  return Math.round(Math.min(1, Math.max(0, s)) * 255);
}

function labToRgb(L, a, b, out, offset) {  // no arrays allocated: it runs once per pixel of a repaint
  const fy = (L + 16.0) / 116.0;
  const x = labInverse(fy + a / 500.0) * D65[0], y = labInverse(fy) * D65[1], z = labInverse(fy - b / 200.0) * D65[2];
  for (let c = 0; c < 3; c++) {
    const m = XYZ_TO_SRGB[c];
    out[offset + c] = linearToSrgb8(m[0] * x + m[1] * y + m[2] * z);
  }
  out[offset + 3] = 255;
}

function cssColour(L, a, b) {
  const rgb = new Uint8ClampedArray(4);
  labToRgb(L, a, b, rgb, 0);
  return `rgb(${rgb[0]},${rgb[1]},${rgb[2]})`;
}

// --- the map ------------------------------------------------------------------------------------------------
async function loadMap() {
  const response = await api("/api/map.lab", {raw: true});
  const width = +response.headers.get("X-Map-Width");
  const height = +response.headers.get("X-Map-Height");
  const version = +response.headers.get("X-Map-Version");
  const lab = new Float32Array(await response.arrayBuffer());
  const sizeChanged = !S.map || S.map.width !== width || S.map.height !== height;
  const canvas = sizeChanged ? document.createElement("canvas") : S.map.canvas;
  canvas.width = width;
  canvas.height = height;
  const image = new ImageData(width, height);
  S.map = {width, height, lab, version, image, canvas};
  repaintRegion(0, 0, width, height);
  updatePointsPlaceholder();
  return sizeChanged;
}

function repaintRegion(x0, y0, x1, y1) {
  const {width, lab, image, canvas} = S.map;
  const data = image.data;
  let L = NaN, a = NaN, b = NaN, last = -1;  // a run of equal colours (flat areas) is converted once
  for (let y = y0; y < y1; y++) {
    for (let x = x0; x < x1; x++) {
      const i = y * width + x;
      if (last >= 0 && lab[3 * i] === L && lab[3 * i + 1] === a && lab[3 * i + 2] === b) {
        data[4 * i] = data[last]; data[4 * i + 1] = data[last + 1]; data[4 * i + 2] = data[last + 2]; data[4 * i + 3] = 255;
      } else {
        L = lab[3 * i]; a = lab[3 * i + 1]; b = lab[3 * i + 2]; last = 4 * i;
        labToRgb(L, a, b, data, last);
      }
    }
  }
  canvas.getContext("2d").putImageData(image, 0, 0, x0, y0, x1 - x0, y1 - y0);
}

function mapSide() {
  return S.map ? Math.max(S.map.width, S.map.height) : 1;
}

// --- views: one zoom and pan for both -----------------------------------------------------------------------
function resizeCanvas(canvas) {
  const ratio = window.devicePixelRatio || 1;
  const width = Math.max(1, Math.round(canvas.clientWidth * ratio));
  const height = Math.max(1, Math.round(canvas.clientHeight * ratio));
  if (canvas.width !== width || canvas.height !== height) {
    canvas.width = width;
    canvas.height = height;
  }
}

function fitView() {
  if (!S.map) return;
  const canvas = $("map-view");
  resizeCanvas(canvas);
  const zoom = 0.95 * Math.min(canvas.width / S.map.width, canvas.height / S.map.height);
  S.view = {zoom, x: (canvas.width - zoom * S.map.width) / 2, y: (canvas.height - zoom * S.map.height) / 2};
  saveSetting("view", [S.view.zoom, S.view.x, S.view.y]);
  draw();
}

function toMap(canvas, event) {  // event position -> map pixels (continuous)
  const rect = canvas.getBoundingClientRect();
  const ratio = canvas.width / rect.width;
  const sx = (event.clientX - rect.left) * ratio;
  const sy = (event.clientY - rect.top) * ratio;
  return {x: (sx - S.view.x) / S.view.zoom, y: (sy - S.view.y) / S.view.zoom, sx, sy};
}

let drawRequested = false;
function draw() {
  if (drawRequested) return;
  drawRequested = true;
  requestAnimationFrame(() => {
    drawRequested = false;
    drawMapView();
    drawPointsView();
  });
}

// A view's 2D context, sized to its box and cleared; null while no map is open.
function clearedView(id) {
  const canvas = $(id);
  resizeCanvas(canvas);
  const ctx = canvas.getContext("2d");
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  return S.map ? ctx : null;
}

function drawMapView() {
  const ctx = clearedView("map-view");
  if (!ctx) return;
  const {zoom, x, y} = S.view;
  ctx.setTransform(zoom, 0, 0, zoom, x, y);
  ctx.imageSmoothingEnabled = zoom < 1;
  ctx.drawImage(S.map.canvas, 0, 0);
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  // overlays in screen pixels
  const drag = S.drag;
  if (drag && drag.kind === "lasso" && drag.path.length > 1) {
    ctx.lineWidth = 2;
    ctx.setLineDash([6, 4]);
    ctx.strokeStyle = "#fff";
    ctx.beginPath();
    drag.path.forEach((p, k) => (k ? ctx.lineTo : ctx.moveTo).call(ctx, p.x * zoom + x, p.y * zoom + y));
    ctx.closePath();
    ctx.stroke();
    ctx.setLineDash([]);
  }
  if (drag && (drag.kind === "fill" || drag.kind === "gradient")) {
    const ax = drag.start.x * zoom + x, ay = drag.start.y * zoom + y;
    const bx = drag.end.x * zoom + x, by = drag.end.y * zoom + y;
    ctx.lineWidth = 2;
    ctx.setLineDash([6, 4]);
    ctx.strokeStyle = "#fff";
    if (drag.kind === "fill") ctx.strokeRect(ax, ay, bx - ax, by - ay);
    else { ctx.beginPath(); ctx.moveTo(ax, ay); ctx.lineTo(bx, by); ctx.stroke(); }
    ctx.setLineDash([]);
  }
  const tool = S.settings.tool;
  if (S.cursor && ["density", "correlation", "eraser"].includes(tool)) {
    const r = (S.settings.size / 2) * zoom;
    const cx = S.cursor.x * zoom + x, cy = S.cursor.y * zoom + y;
    ctx.lineWidth = 1;
    ctx.strokeStyle = "rgba(0,0,0,0.8)";
    ctx.beginPath(); ctx.arc(cx, cy, r, 0, 2 * Math.PI); ctx.stroke();
    ctx.strokeStyle = "rgba(255,255,255,0.9)";
    ctx.beginPath(); ctx.arc(cx, cy, Math.max(1, r - 1), 0, 2 * Math.PI); ctx.stroke();
    if (S.settings.hardness < 1) {
      ctx.setLineDash([3, 3]);
      ctx.beginPath(); ctx.arc(cx, cy, r * S.settings.hardness, 0, 2 * Math.PI); ctx.stroke();
      ctx.setLineDash([]);
    }
  }
}

function drawPointsView() {
  const ctx = clearedView("points-view");
  if (!ctx) return;
  const {zoom, x, y} = S.view;
  ctx.fillStyle = "#fff";  // the paper: the map's domain
  ctx.fillRect(x, y, S.map.width * zoom, S.map.height * zoom);
  if (S.settings.overlay > 0) {  // the map under the points
    ctx.globalAlpha = S.settings.overlay;
    ctx.setTransform(zoom, 0, 0, zoom, x, y);
    ctx.imageSmoothingEnabled = zoom < 1;
    ctx.drawImage(S.map.canvas, 0, 0);
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.globalAlpha = 1;
  }
  const points = S.points;
  if (!points) return;
  const side = mapSide();
  const scale = side * zoom;  // map units -> screen pixels
  const [w, h] = points.domain;
  const radius = Math.max(0.6, 0.3 * Math.sqrt((w * h) / Math.max(points.n, 1)) * scale);
  const xy = points.xy;
  ctx.fillStyle = "#000";
  ctx.globalAlpha = points.final ? 1 : 0.75;
  if (radius < 1.5) {
    const d = 2 * radius;
    for (let i = 0; i < xy.length; i += 2) ctx.fillRect(xy[i] * scale + x - radius, xy[i + 1] * scale + y - radius, d, d);
  } else {
    ctx.beginPath();
    for (let i = 0; i < xy.length; i += 2) {
      const px = xy[i] * scale + x, py = xy[i + 1] * scale + y;
      ctx.moveTo(px + radius, py);
      ctx.arc(px, py, radius, 0, 2 * Math.PI);
    }
    ctx.fill();
  }
  ctx.globalAlpha = 1;
}

function zoomAt(sx, sy, factor) {
  const zoom = Math.min(64, Math.max(0.02, S.view.zoom * factor));
  const real = zoom / S.view.zoom;
  S.view = {zoom, x: sx - (sx - S.view.x) * real, y: sy - (sy - S.view.y) * real};
  saveSetting("view", [S.view.zoom, S.view.x, S.view.y]);
  draw();
}

// --- brush strokes: painted here at once, sent as one edit --------------------------------------------------
function falloff(r, radius, inner) {
  if (radius - inner <= 1e-9) return r < radius ? 1.0 : 0.0;
  const t = Math.min(1, Math.max(0, (radius - r) / (radius - inner)));
  return t * t * (3.0 - 2.0 * t);
}

function beginStroke(point) {
  const tool = S.settings.tool;
  const pixels = S.map.width * S.map.height;
  if (!S.strokeWeight || S.strokeWeight.length !== pixels) {  // kept between strokes: no 12 MB copy per stroke
    S.strokeWeight = new Float64Array(pixels);  // max falloff so far, per pixel; 0 = untouched
    S.strokeBase = new Float32Array(3 * pixels);  // the map before the stroke, saved where it touches
  }
  S.stroke = {
    kind: tool, centres: [], size: S.settings.size, hardness: S.settings.hardness, strength: S.settings.strength,
    mode: S.settings.mode, ab: S.settings.ab.slice(), base: S.strokeBase, weight: S.strokeWeight,
    box: [Infinity, Infinity, -Infinity, -Infinity],  // x0, y0, x1, y1 of the touched pixels
  };
  addStamp(point.x, point.y);
}

function extendStroke(point) {
  const stroke = S.stroke;
  const last = stroke.centres[stroke.centres.length - 1];
  const spacing = Math.max(0.5, stroke.size / 8);
  const dx = point.x - last[0], dy = point.y - last[1];
  const distance = Math.hypot(dx, dy);
  const steps = Math.floor(distance / spacing);
  for (let k = 1; k <= steps; k++) addStamp(last[0] + (dx * k * spacing) / distance, last[1] + (dy * k * spacing) / distance);
}

function addStamp(cx, cy) {
  const stroke = S.stroke;
  cx = Math.round(cx * 100) / 100;
  cy = Math.round(cy * 100) / 100;
  stroke.centres.push([cx, cy]);
  if (stroke.kind === "eraser") return;  // the eraser is shown when the server has it
  const {width, height, lab} = S.map;
  const radius = stroke.size / 2, inner = stroke.hardness * radius;
  const x0 = Math.max(0, Math.floor(cx - radius)), x1 = Math.min(width, Math.ceil(cx + radius) + 1);
  const y0 = Math.max(0, Math.floor(cy - radius)), y1 = Math.min(height, Math.ceil(cy + radius) + 1);
  if (x0 >= x1 || y0 >= y1) return;
  const {weight, base, strength, box} = stroke;
  box[0] = Math.min(box[0], x0); box[1] = Math.min(box[1], y0); box[2] = Math.max(box[2], x1); box[3] = Math.max(box[3], y1);
  const [ta, tb] = stroke.ab;
  for (let y = y0; y < y1; y++) {
    const dy = y + 0.5 - cy;
    for (let x = x0; x < x1; x++) {
      const dx = x + 0.5 - cx;
      const f = falloff(Math.sqrt(dy * dy + dx * dx), radius, inner);
      const i = y * width + x;
      if (f <= weight[i]) continue;
      if (weight[i] === 0) { base[3 * i] = lab[3 * i]; base[3 * i + 1] = lab[3 * i + 1]; base[3 * i + 2] = lab[3 * i + 2]; }
      weight[i] = f;
      const w = weight[i] * strength;
      if (stroke.kind === "density") {
        const L = base[3 * i];
        lab[3 * i] = stroke.mode === "darken" ? L * (1.0 - w) : L + w * (100.0 - L);
      } else {
        const a = base[3 * i + 1], b = base[3 * i + 2];
        lab[3 * i + 1] = a + w * (ta - a);
        lab[3 * i + 2] = b + w * (tb - b);
      }
    }
  }
  repaintRegion(x0, y0, x1, y1);
  draw();
}

function endStroke() {
  const stroke = S.stroke;
  S.stroke = null;
  if (!stroke || !stroke.centres.length) return;
  const [x0, y0, x1, y1] = stroke.box;  // clear the weights for the next stroke
  for (let y = y0; y < y1; y++) stroke.weight.fill(0, y * S.map.width + x0, y * S.map.width + x1);
  const edit = {type: stroke.kind, centres: stroke.centres, size: stroke.size, hardness: stroke.hardness, strength: stroke.strength};
  if (stroke.kind === "density") edit.mode = stroke.mode;
  if (stroke.kind === "correlation") edit.ab = stroke.ab;
  sendEdit(edit, stroke.kind === "eraser");
}

function sendEdit(edit, reload) {
  return enqueue(async () => {
    try {
      const summary = await api("/api/edit", {method: "POST", json: edit});
      if (reload || summary.width !== S.map.width || summary.height !== S.map.height) {
        const resized = await loadMap();
        if (resized) fitView();
      }
      S.map.version = summary.version;
      afterChange(summary);
    } catch (error) {
      fail(error);
      await loadMap().catch(() => {});  // back to the server's map
      draw();
    }
  });
}

function afterChange(summary) {
  $("undo").disabled = !summary.can_undo;
  $("redo").disabled = !summary.can_redo;
  $("undo").title = summary.can_undo ? `Undo ${summary.undo[summary.undo.length - 1]} (Ctrl+Z)` : "Nothing to undo";
  $("redo").title = summary.can_redo ? `Redo ${summary.redo[0]} (Ctrl+Y)` : "Nothing to redo";
  draw();
  refreshStatus();
  if (S.settings.auto) {
    clearTimeout(S.autoTimer);
    S.autoTimer = setTimeout(() => synthesize(), 400);
  }
}

async function historyStep(which) {
  return enqueue(async () => {
    try {
      const summary = await api(`/api/${which}`, {method: "POST"});
      const resized = await loadMap();
      if (resized) fitView();
      afterChange(summary);
      setStatus(`${which === "undo" ? "Undid" : "Redid"} ${summary.label}`);
    } catch (error) { fail(error); }
  });
}

// --- pointer handling on both views -------------------------------------------------------------------------
function onPointerDown(event) {
  const canvas = event.currentTarget;
  if (!S.map) return;
  const point = toMap(canvas, event);
  const isMap = canvas.id === "map-view";
  const tool = S.settings.tool;
  try { canvas.setPointerCapture(event.pointerId); } catch (error) { /* a synthetic pointer (tests, benchmarks) */ }
  if (event.button === 1 || event.button === 2 || S.space || tool === "pan" || !isMap) {
    S.drag = {kind: "pan", sx: point.sx, sy: point.sy, view: {...S.view}};
  } else if (event.button === 0 && ["density", "correlation", "eraser"].includes(tool)) {
    beginStroke(point);
  } else if (event.button === 0 && (tool === "fill" || tool === "gradient")) {
    S.drag = {kind: tool, start: point, end: point};
  } else if (event.button === 0 && tool === "lasso") {
    S.drag = {kind: "lasso", path: [point]};
  } else if (event.button === 0 && tool === "wand") {
    sendEdit(fillEdit({seed: [point.x, point.y], tolerance: S.settings.tolerance}), true);
  }
  event.preventDefault();
}

function onPointerMove(event) {
  const canvas = event.currentTarget;
  if (!S.map) return;
  const point = toMap(canvas, event);
  S.cursor = canvas.id === "map-view" ? point : null;
  showCursor(point);
  if (S.stroke) extendStroke(point);
  else if (S.drag && S.drag.kind === "pan") {
    S.view = {zoom: S.drag.view.zoom, x: S.drag.view.x + point.sx - S.drag.sx, y: S.drag.view.y + point.sy - S.drag.sy};
  } else if (S.drag && S.drag.kind === "lasso") {
    const last = S.drag.path[S.drag.path.length - 1];
    if (Math.hypot(point.x - last.x, point.y - last.y) * S.view.zoom >= 3) S.drag.path.push(point);
  } else if (S.drag) S.drag.end = point;
  draw();
}

function onPointerUp(event) {
  if (S.stroke) endStroke();
  const drag = S.drag;
  S.drag = null;
  if (!drag) return;
  if (drag.kind === "pan") saveSetting("view", [S.view.zoom, S.view.x, S.view.y]);
  else if (drag.kind === "fill") {
    sendEdit(fillEdit({rect: [drag.start.x, drag.start.y, drag.end.x, drag.end.y]}), true);
  } else if (drag.kind === "lasso") {
    if (drag.path.length >= 3) sendEdit(fillEdit({polygon: drag.path.map((p) => [p.x, p.y])}), true);
  } else if (drag.kind === "gradient") {
    if (Math.hypot(drag.end.x - drag.start.x, drag.end.y - drag.start.y) < 1) return;
    sendEdit({type: "gradient", start: [drag.start.x, drag.start.y], end: [drag.end.x, drag.end.y], values: S.settings.gradient}, true);
  }
  draw();
}

function fillEdit(selection) {  // the current colour, and the fill density if ticked, into a selection
  const edit = {type: "fill", ...selection, ab: S.settings.ab};
  if (S.settings.fill_density !== null && S.settings.fill_density !== undefined) edit.density = S.settings.fill_density;
  return edit;
}

function nearestPreset(a, b) {
  let best = null, distance = Infinity;
  for (const [name, [pa, pb]] of Object.entries(S.presets)) {
    const d = Math.hypot(pa - a, pb - b);
    if (d < distance) { distance = d; best = name; }
  }
  return best;
}

function showCursor(point) {
  const {width, height, lab} = S.map;
  const x = Math.floor(point.x), y = Math.floor(point.y);
  if (x < 0 || y < 0 || x >= width || y >= height) { $("cursor").textContent = ""; return; }
  const i = y * width + x;
  const L = lab[3 * i], a = lab[3 * i + 1], b = lab[3 * i + 2];
  const preset = nearestPreset(a, b);
  $("cursor").textContent = `x ${x}, y ${y} · density ${(1 - L / 100).toFixed(2)} · (a ${a.toFixed(0)}, b ${b.toFixed(0)})` +
    (preset ? ` ≈ ${preset}` : "");
}

// --- synthesis ----------------------------------------------------------------------------------------------
async function synthesize() {
  clearTimeout(S.autoTimer);
  S.timing = {start: performance.now(), firstPoints: null, firstWasPartial: null, final: null};
  const body = {};
  const count = $("points-count").value.trim();
  if (count) body.points = Math.round(+count);
  body.seed = Math.round(+$("seed").value || 0);
  setStatus("Starting a synthesis…");  // at once: the last one's "Done" is gone when the click returns
  await enqueue(async () => {
    try {
      const status = await api("/api/synthesize", {method: "POST", json: body});
      if (!S.events) { setStatus(status.text); startPolling(); }  // else the events report it, in order
    } catch (error) { fail(error); }
  });
}

// Progress comes by Server-Sent Events (GET /api/events): a "points" event says a newer frame is available (then
// fetched from points.bin), a "status" event carries the status line; each is handled after the ones before it,
// so "Done: N points" shows once the final points are drawn. Polling (startPolling) is only the fallback for when
// the EventSource errors for good (the browser closed it: refused, or no event stream) or does not exist; while it
// reconnects by itself (a dropped connection), the stream's first events on reconnecting bring the page up to date.
function listenForProgress() {
  if (!window.EventSource) return;
  const source = new EventSource(withToken("/api/events"));
  S.events = source;
  const then = (task) => { S.eventTasks = S.eventTasks.then(task).catch(fail); };
  source.addEventListener("points", (event) => {
    const frame = JSON.parse(event.data);
    then(async () => {
      if (frame.frame <= S.frame) return;
      const newer = await fetchPoints(S.frame);
      if (newer.points) showPoints(newer);
    });
  });
  source.addEventListener("status", (event) => { const status = JSON.parse(event.data); then(() => showStatus(status)); });
  source.addEventListener("error", () => {
    if (source.readyState !== EventSource.CLOSED) return;  // the browser reconnects by itself
    S.events = null;  // the fallback: polling from now on
    refreshStatus();  // polls if a synthesis runs
  });
}

function startPolling() {
  if (S.polling) return;
  S.polling = true;
  const tick = async () => {
    let again = false;
    try {
      const frame = await fetchPoints(S.frame);
      if (frame.points) showPoints(frame);
      const status = frame.status;
      setStatus(status.text);
      again = status.job.state === "running" || frame.points !== null;
    } catch (error) { fail(error); }
    if (again) setTimeout(tick, 120);
    else { S.polling = false; refreshStatus(); }
  };
  tick();
}

async function fetchPoints(since) {  // the newest frame if newer than `since`: binary float32 points, the rest in a header
  const response = await api(`/api/points.bin?since=${since}`, {raw: true});
  const frame = JSON.parse(response.headers.get("X-Points"));
  frame.points = response.status === 204 ? null : new Float32Array(await response.arrayBuffer());
  return frame;
}

function showPoints(frame) {
  S.frame = frame.frame;
  const timing = S.timing;  // click to first and to final points, in ms (read by the browser test)
  if (timing && timing.firstPoints === null) { timing.firstPoints = performance.now() - timing.start; timing.firstWasPartial = !frame.final; }
  if (timing && frame.final && timing.final === null) timing.final = performance.now() - timing.start;
  S.points = {xy: Float64Array.from(frame.points), n: frame.n, domain: frame.domain, final: frame.final, version: frame.version};
  $("points-caption").textContent = frame.final ? `${frame.n} points` : `${frame.n} points forming: iteration ${frame.iteration} of ${frame.total}`;
  draw();
}

function updatePointsPlaceholder() {
  if (!S.map) return;
  let ink = 0;
  const lab = S.map.lab;
  for (let i = 0; i < lab.length; i += 3) ink += 1 - lab[i] / 100;
  const perInk = S.settings.points_per_ink || 50000;
  $("points-count").placeholder = `auto: ${Math.round((perInk * ink) / (lab.length / 3))}`;
}

function showStatus(status) {  // a status as GET /api/status gives it
  setStatus(status.text, status.job && status.job.state === "error");
  $("undo").disabled = !status.can_undo;
  $("redo").disabled = !status.can_redo;
}

async function refreshStatus() {
  try {
    const status = await api("/api/status");
    showStatus(status);
    if (status.job && status.job.state === "running" && !S.events) startPolling();
  } catch (error) { fail(error); }
}

// --- settings: saved in the project, restored on reload -----------------------------------------------------
function saveSetting(key, value) {
  S.settings[key] = value;
  S.pendingSettings[key] = value;
  clearTimeout(S.settingsTimer);
  S.settingsTimer = setTimeout(flushSettings, 250);
}

async function flushSettings() {
  const changes = S.pendingSettings;
  S.pendingSettings = {};
  if (!Object.keys(changes).length) return;
  try { await api("/api/settings", {method: "POST", json: changes}); } catch (error) { fail(error); }
}

function applySettingsToControls() {
  const s = S.settings;
  document.querySelectorAll(".tool").forEach((b) => b.classList.toggle("active", b.dataset.tool === s.tool));
  document.querySelectorAll("input[name=mode]").forEach((r) => { r.checked = r.value === s.mode; });
  for (const key of ["size", "hardness", "strength"]) {
    $(key).value = s[key];
    $(`${key}-value`).textContent = key === "size" ? `${s[key]} px` : (+s[key]).toFixed(2);
  }
  $("points-count").value = s.points === null || s.points === undefined ? "" : s.points;
  $("seed").value = s.seed;
  $("auto").checked = !!s.auto;
  $("gradient-from").value = s.gradient[0];
  $("gradient-to").value = s.gradient[1];
  $("tolerance").value = s.tolerance;
  $("overlay").value = s.overlay;
  $("fill-with-density").checked = s.fill_density !== null && s.fill_density !== undefined;
  if ($("fill-with-density").checked) $("fill-density").value = s.fill_density;
  showCurrentColour();
}

function showCurrentColour() {
  const [a, b] = S.settings.ab;
  $("current-swatch").style.background = cssColour(70, a, b);
  const preset = nearestPreset(a, b);
  $("current-label").textContent = `(${a.toFixed(0)}, ${b.toFixed(0)})${preset ? " ≈ " + preset : ""}`;
  placeMarker(a, b);
}

function setTool(tool) {
  saveSetting("tool", tool);
  applySettingsToControls();
  draw();
}

// --- the palette picker -------------------------------------------------------------------------------------
function paletteAb(event) {  // mouse position over the picture -> (a, b), or null outside the plane
  const image = $("palette-image");
  const rect = image.getBoundingClientRect();
  const p = S.picture;
  const px = ((event.clientX - rect.left) * p.width) / rect.width;
  const py = ((event.clientY - rect.top) * p.height) / rect.height;
  const u = (px - p.left) / p.side, v = (py - p.top) / p.side;
  if (u < 0 || u > 1 || v < 0 || v > 1) return null;
  return [Math.round(-128 + 255 * u), Math.round(127 - 255 * v)];
}

function placeMarker(a, b) {
  const p = S.picture;
  const image = $("palette-image");
  if (!p || !image.clientWidth) return;
  const marker = $("palette-marker");
  const u = (a + 128) / 255, v = (127 - b) / 255;
  marker.style.left = `${((p.left + u * p.side) / p.width) * image.clientWidth}px`;
  marker.style.top = `${((p.top + v * p.side) / p.height) * image.clientHeight}px`;
}

async function hoverPalette(ab) {
  const request = ++S.hoverRequest;
  try {
    const example = await api(`/api/palette/example?a=${ab[0]}&b=${ab[1]}&n=250`);
    if (request !== S.hoverRequest) return;  // a newer hover won
    drawExample(example);
  } catch (error) { /* hovering never breaks the page */ }
}

function drawExample(example) {
  const canvas = $("palette-hover");
  const ctx = canvas.getContext("2d");
  ctx.fillStyle = cssColour(92, example.a, example.b);
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = "#111";
  const r = 2.2;
  ctx.beginPath();
  for (let i = 0; i < example.points.length; i += 2) {
    const x = example.points[i] * canvas.width, y = example.points[i + 1] * canvas.height;
    ctx.moveTo(x + r, y);
    ctx.arc(x, y, r, 0, 2 * Math.PI);
  }
  ctx.fill();
  $("hover-label").textContent = `(a ${example.a}, b ${example.b}) ≈ ${example.nearest_preset}` +
    (example.populated ? "" : " · outside the palette's corpus: the nearest example shown");
}

function pickColour(ab) {
  saveSetting("ab", ab);
  if (!["correlation", "fill", "lasso", "wand"].includes(S.settings.tool)) saveSetting("tool", "correlation");
  applySettingsToControls();
  hoverPalette(ab);
}

async function loadPalette() {
  const info = await api("/api/palette");
  S.presets = info.presets;
  S.picture = info.picture;
  const image = $("palette-image");
  image.onload = () => showCurrentColour();
  image.src = withToken("/api/palette.png");
  const box = $("presets");
  box.textContent = "";
  for (const [name, [a, b]] of Object.entries(info.presets)) {
    const button = document.createElement("button");
    button.dataset.testid = `preset-${name}`;
    button.title = `${name}: (a ${a}, b ${b})`;
    const dot = document.createElement("span");
    dot.className = "dot";
    dot.style.background = cssColour(70, a, b);
    button.append(dot, name);
    button.addEventListener("click", () => pickColour([a, b]));
    button.addEventListener("mouseenter", () => hoverPalette([a, b]));
    box.append(button);
  }
  showCurrentColour();
}

// --- open, new, expand, export ------------------------------------------------------------------------------
async function openFile(file) {
  const isPoints = /\.(txt|csv|xy|pts|npy)$/i.test(file.name);
  let query = `name=${encodeURIComponent(file.name)}`;
  if (!isPoints && $("photo").checked) {
    query += `&as=photo&gamma=${+$("photo-gamma").value || 1}&invert=${$("photo-invert").checked}` +
      `&correlation=${encodeURIComponent(S.settings.ab.join(","))}`;
  }
  setStatus(isPoints ? `Inferring the map of ${file.name} with the network (a few seconds)…` : `Opening ${file.name}…`);
  await enqueue(async () => {
    try {
      const summary = await api(`/api/open?${query}`, {method: "POST", body: file});
      await loadMap();
      fitView();
      afterChange(summary);
      if (summary.warning) setStatus(`Opened ${file.name} (${summary.warning})`);
    } catch (error) { fail(error); }
  });
}

async function newMap() {
  await enqueue(async () => {
    try {
      const summary = await api("/api/new", {method: "POST", json: {width: 512, height: 512, density: 0.3, correlation: "blue"}});
      await loadMap();
      fitView();
      afterChange(summary);
    } catch (error) { fail(error); }
  });
}

function expandCanvas() {
  const margins = ["left", "top", "right", "bottom"].map((side) => Math.max(0, Math.round(+$(`expand-${side}`).value || 0)));
  let fill = $("expand-fill").value === "content-aware" ? "content-aware" : null;
  if ($("expand-fill").value === "colour") {
    const density = S.settings.fill_density === null || S.settings.fill_density === undefined ? 0.3 : S.settings.fill_density;
    fill = [100 * (1 - density), S.settings.ab[0], S.settings.ab[1]];
  }
  sendEdit({type: "expand", margins, fill}, true);
}

function updateExportLinks() {
  $("export-points").href = withToken(`/api/export/${$("points-format").value}`);
  $("export-map").href = withToken(`/api/export/${$("map-format").value}`);
}

// --- wiring -------------------------------------------------------------------------------------------------
function wire() {
  for (const id of ["map-view", "points-view"]) {
    const canvas = $(id);
    canvas.addEventListener("pointerdown", onPointerDown);
    canvas.addEventListener("pointermove", onPointerMove);
    canvas.addEventListener("pointerup", onPointerUp);
    canvas.addEventListener("pointercancel", onPointerUp);
    canvas.addEventListener("pointerleave", () => { S.cursor = null; draw(); });
    canvas.addEventListener("contextmenu", (event) => event.preventDefault());
    canvas.addEventListener("dblclick", fitView);
    canvas.addEventListener("wheel", (event) => {
      event.preventDefault();
      const point = toMap(canvas, event);
      zoomAt(point.sx, point.sy, Math.exp(-event.deltaY * 0.0015));
    }, {passive: false});
  }
  document.querySelectorAll(".tool").forEach((button) => button.addEventListener("click", () => setTool(button.dataset.tool)));
  document.querySelectorAll("input[name=mode]").forEach((radio) => radio.addEventListener("change", () => saveSetting("mode", radio.value)));
  for (const key of ["size", "hardness", "strength"]) {
    $(key).addEventListener("input", () => { saveSetting(key, +$(key).value); applySettingsToControls(); draw(); });
  }
  $("undo").addEventListener("click", () => historyStep("undo"));
  $("redo").addEventListener("click", () => historyStep("redo"));
  $("synthesize").addEventListener("click", () => synthesize());
  $("cancel").addEventListener("click", async () => { try { await api("/api/cancel", {method: "POST"}); refreshStatus(); } catch (e) { fail(e); } });
  $("auto").addEventListener("change", () => saveSetting("auto", $("auto").checked));
  $("points-count").addEventListener("change", () => {
    const value = $("points-count").value.trim();
    saveSetting("points", value ? Math.max(2, Math.round(+value)) : null);
  });
  $("seed").addEventListener("change", () => saveSetting("seed", Math.max(0, Math.round(+$("seed").value || 0))));
  for (const id of ["gradient-from", "gradient-to"]) {
    $(id).addEventListener("change", () => saveSetting("gradient", [+$("gradient-from").value, +$("gradient-to").value].map((v) => Math.min(1, Math.max(0, v)))));
  }
  const fillChanged = () => saveSetting("fill_density", $("fill-with-density").checked ? Math.min(1, Math.max(0, +$("fill-density").value)) : null);
  $("fill-with-density").addEventListener("change", fillChanged);
  $("fill-density").addEventListener("change", fillChanged);
  $("expand").addEventListener("click", expandCanvas);
  $("tolerance").addEventListener("change", () => saveSetting("tolerance", Math.min(400, Math.max(0, +$("tolerance").value || 0))));
  $("overlay").addEventListener("input", () => { saveSetting("overlay", +$("overlay").value); draw(); });
  $("open-file").addEventListener("change", (event) => { if (event.target.files[0]) openFile(event.target.files[0]); event.target.value = ""; });
  $("new-map").addEventListener("click", newMap);
  $("points-format").addEventListener("change", updateExportLinks);
  $("map-format").addEventListener("change", updateExportLinks);
  const palette = $("palette");
  let lastHover = 0;
  palette.addEventListener("mousemove", (event) => {
    const ab = paletteAb(event);
    const now = performance.now();
    if (ab && now - lastHover > 40) { lastHover = now; hoverPalette(ab); }
  });
  palette.addEventListener("click", (event) => { const ab = paletteAb(event); if (ab) pickColour(ab); });
  window.addEventListener("keydown", (event) => {
    if (event.target.tagName === "INPUT" && event.target.type !== "checkbox" && event.target.type !== "radio" && event.target.type !== "range") return;
    const key = event.key.toLowerCase();
    if ((event.ctrlKey || event.metaKey) && key === "z") { event.preventDefault(); historyStep(event.shiftKey ? "redo" : "undo"); }
    else if ((event.ctrlKey || event.metaKey) && key === "y") { event.preventDefault(); historyStep("redo"); }
    else if (key === " ") { S.space = true; event.preventDefault(); }
  });
  window.addEventListener("keyup", (event) => { if (event.key === " ") S.space = false; });
  window.addEventListener("resize", draw);
  window.addEventListener("beforeunload", () => { clearTimeout(S.settingsTimer); flushSettings(); });
}

async function start() {
  wire();
  updateExportLinks();
  try {
    const state = await api("/api/state");
    S.settings = state.settings;
    applySettingsToControls();
    const palette = loadPalette().catch(fail);  // asked for while the map loads
    const points = fetchPoints(0);
    if (state.width) {
      await loadMap();
      const view = state.settings.view;
      if (view) { S.view = {zoom: view[0], x: view[1], y: view[2]}; draw(); } else fitView();
    }
    afterChangeButtons(state);
    setStatus(state.status.text);
    await palette;
    const frame = await points;
    if (frame.points) showPoints(frame);
    listenForProgress();  // after the state above: its first events are the state now
    if (state.status.job.state === "running" && !S.events) startPolling();
    document.body.dataset.ready = "true";  // for tests: the page has its state
    if (S.presets) hoverPalette(S.settings.ab);  // the current colour's pattern: not needed to start working
  } catch (error) { fail(error); }
}

function afterChangeButtons(summary) {
  $("undo").disabled = !summary.can_undo;
  $("redo").disabled = !summary.can_redo;
}

start();
