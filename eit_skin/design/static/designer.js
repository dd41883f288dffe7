// eit_skin designer: plain browser code, no build step. The server validates every change
// and answers with the model (outline, electrodes, mesh) and the predicted-accuracy preview.
"use strict";

const SIZE = 640;
const designer = {
  data: null, // the patch data being edited (as the YAML file parses)
  good: null, // the last data the server accepted
  model: null, // the server's answer for `good`
  path: null,
  layer: 0,
  selected: -1,
  version: 0, // increases with every model shown (tests wait on it)
  busy: false,
  queued: false,
  lastSave: null,
  view: null,
};
window.designer = designer;

const $ = (id) => document.getElementById(id);
const SVGNS = "http://www.w3.org/2000/svg";

async function post(url, body) {
  const response = await fetch(url, {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify(body),
  });
  return response.json();
}

function layerData() {
  return designer.data.layers[designer.layer];
}

// ----------------------------------------------------------------- view transform (m <-> px)
function makeView(outline) {
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (const [x, y] of outline) {
    x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y);
  }
  const span = Math.max(x1 - x0, y1 - y0);
  const scale = (0.84 * SIZE) / span;
  const cx = 0.5 * (x0 + x1), cy = 0.5 * (y0 + y1);
  return {
    scale,
    px: (x) => SIZE / 2 + (x - cx) * scale,
    py: (y) => SIZE / 2 - (y - cy) * scale,
    x: (px) => cx + (px - SIZE / 2) / scale,
    y: (py) => cy - (py - SIZE / 2) / scale,
  };
}

function pathOf(points, close) {
  const v = designer.view;
  return points.map(([x, y], i) => `${i ? "L" : "M"}${v.px(x).toFixed(2)},${v.py(y).toFixed(2)}`)
    .join("") + (close ? "Z" : "");
}

// ------------------------------------------------------------------------- outline geometry
function arcTable(outline) {
  const cum = [0];
  for (let i = 0; i < outline.length; i++) {
    const a = outline[i], b = outline[(i + 1) % outline.length];
    cum.push(cum[i] + Math.hypot(b[0] - a[0], b[1] - a[1]));
  }
  return cum;
}

function project(outline, x, y) {
  // arc-length fraction of the outline point nearest (x, y)
  const cum = arcTable(outline);
  let best = Infinity, arc = 0;
  for (let i = 0; i < outline.length; i++) {
    const a = outline[i], b = outline[(i + 1) % outline.length];
    const dx = b[0] - a[0], dy = b[1] - a[1];
    const len2 = dx * dx + dy * dy || 1;
    const t = Math.min(1, Math.max(0, ((x - a[0]) * dx + (y - a[1]) * dy) / len2));
    const d = Math.hypot(a[0] + t * dx - x, a[1] + t * dy - y);
    if (d < best) { best = d; arc = cum[i] + t * Math.sqrt(len2); }
  }
  return (arc / cum[outline.length]) % 1;
}

function pointAt(outline, fraction) {
  const cum = arcTable(outline);
  const s = (((fraction % 1) + 1) % 1) * cum[outline.length];
  let i = 0;
  while (i < outline.length - 1 && cum[i + 1] < s) i++;
  const a = outline[i], b = outline[(i + 1) % outline.length];
  const t = (s - cum[i]) / ((cum[i + 1] - cum[i]) || 1);
  return [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
}

// ------------------------------------------------------------------------------ colours
const RAMP = [[252, 253, 191], [252, 137, 97], [183, 55, 121], [81, 18, 124], [0, 0, 4]];
function colour(t) {
  const u = Math.min(1, Math.max(0, t)) * (RAMP.length - 1);
  const i = Math.min(RAMP.length - 2, Math.floor(u)), f = u - i;
  return RAMP[i].map((c, k) => Math.round(c + f * (RAMP[i + 1][k] - c)));
}

// ------------------------------------------------------------------------------- render
function render() {
  const m = designer.model;
  designer.view = makeView(m.outline);
  const v = designer.view;
  $("outline").setAttribute("d", pathOf(m.outline, true));
  const holes = $("holes");
  holes.replaceChildren(...m.holes.map((h) => {
    const p = document.createElementNS(SVGNS, "path");
    p.setAttribute("d", pathOf(h, true));
    return p;
  }));
  const nodes = m.mesh.nodes;
  $("mesh").setAttribute("d", m.mesh.triangles.map(([a, b, c]) =>
    pathOf([nodes[a], nodes[b], nodes[c]], true)).join(""));
  renderMap();
  const targets = $("targets");
  targets.replaceChildren();
  const chains = m.electrodes.map((e) => {
    const p = document.createElementNS(SVGNS, "path");
    p.setAttribute("class", "electrode-chain");
    p.setAttribute("d", pathOf(e.chain, false));
    return p;
  });
  const handles = m.electrodes.map((e, k) => {
    const r = document.createElementNS(SVGNS, "rect");
    r.setAttribute("class", "electrode" + (k === designer.selected ? " selected" : ""));
    r.setAttribute("data-index", k);
    r.setAttribute("width", 12); r.setAttribute("height", 12);
    r.setAttribute("x", v.px(e.center[0]) - 6); r.setAttribute("y", v.py(e.center[1]) - 6);
    r.addEventListener("mousedown", (ev) => startDrag(ev, k));
    return r;
  });
  $("electrodes").replaceChildren(...chains, ...handles);
  const el = layerData().electrodes;
  $("width").value = +(el.width * 1e3).toFixed(4);
  const protocol = layerData().protocol || {};
  $("drive").value = protocol.drive || "adjacent";
  $("measure").value = protocol.measure || "adjacent";
  const mesh = layerData().mesh || {};
  $("max-edge").value = mesh.max_edge ? +(mesh.max_edge * 1e3).toFixed(4) : "";
  const target = (layerData().solver || {}).accuracy_target;
  $("target").value = target ? target.position_error_percent : "";
  $("hash").textContent = "content hash " + m.content_hash.slice(0, 16);
  const select = $("layer");
  select.replaceChildren(...m.layer_names.map((name, i) => {
    const o = document.createElement("option");
    o.value = i; o.textContent = name;
    return o;
  }));
  select.value = designer.layer;
  const t = m.timings_s;
  $("status").textContent =
    `model took ${t.all.toFixed(2)} s (mesh ${t.mesh.toFixed(2)}, build ${t.build.toFixed(2)}, ` +
    `simulate ${t.simulate.toFixed(2)}, image ${t.image.toFixed(2)} s): ` +
    `${m.mesh.n_triangles} triangles, ${m.prediction.targets} targets`;
  $("summary").textContent = m.prediction.line;
}

function renderMap() {
  const m = designer.model, v = designer.view, p = m.prediction;
  const kind = $("map-kind").value;
  const rows = p.maps[kind];
  const h = rows.length, w = rows[0].length;
  let lo = Infinity, hi = -Infinity;
  for (const row of rows) for (const val of row) {
    if (val !== null) { lo = Math.min(lo, val); hi = Math.max(hi, val); }
  }
  const canvas = document.createElement("canvas");
  canvas.width = w; canvas.height = h;
  const ctx = canvas.getContext("2d");
  const img = ctx.createImageData(w, h);
  for (let r = 0; r < h; r++) for (let c = 0; c < w; c++) {
    const val = rows[h - 1 - r][c]; // image rows top = largest y
    const k = 4 * (r * w + c);
    if (val === null) { img.data[k + 3] = 0; continue; }
    const [R, G, B] = colour((val - lo) / ((hi - lo) || 1));
    img.data[k] = R; img.data[k + 1] = G; img.data[k + 2] = B; img.data[k + 3] = 255;
  }
  ctx.putImageData(img, 0, 0);
  const dx = p.x_m.length > 1 ? p.x_m[1] - p.x_m[0] : 0;
  const dy = p.y_m.length > 1 ? p.y_m[1] - p.y_m[0] : 0;
  const x0 = p.x_m[0] - dx / 2, x1 = p.x_m[p.x_m.length - 1] + dx / 2;
  const y0 = p.y_m[0] - dy / 2, y1 = p.y_m[p.y_m.length - 1] + dy / 2;
  const image = $("map");
  image.setAttribute("href", canvas.toDataURL());
  image.setAttribute("x", v.px(x0)); image.setAttribute("y", v.py(y1));
  image.setAttribute("width", v.px(x1) - v.px(x0)); image.setAttribute("height", v.py(y0) - v.py(y1));
  image.setAttribute("style", "image-rendering: pixelated");
  const unit = kind === "position_error_m" ? 1e3 : 1;
  const name = kind === "position_error_m" ? "position error [mm]" : kind.replace("_", " ");
  $("legend").textContent = `${name}: light ${(lo * unit).toFixed(3)} .. dark ${(hi * unit).toFixed(3)}`;
}

// ------------------------------------------------------------------------------ editing
function fractions() {
  return designer.model.electrodes.map((e) => e.fraction);
}

function setFractions(values) {
  const el = layerData().electrodes;
  for (const key of ["layout", "count", "start_angle_deg", "start_fraction"]) delete el[key];
  const sorted = values.map((f) => +((((f % 1) + 1) % 1).toFixed(6))).sort((a, b) => a - b);
  el.positions = sorted;
}

function startDrag(ev, k) {
  ev.preventDefault();
  designer.selected = k;
  const handle = ev.target;
  const svg = $("sheet");
  const outline = designer.model.outline;
  let fraction = designer.model.electrodes[k].fraction;
  const move = (e) => {
    const box = svg.getBoundingClientRect();
    const v = designer.view;
    fraction = project(outline, v.x(e.clientX - box.left), v.y(e.clientY - box.top));
    const [x, y] = pointAt(outline, fraction);
    handle.setAttribute("x", v.px(x) - 6); handle.setAttribute("y", v.py(y) - 6);
  };
  const up = () => {
    window.removeEventListener("mousemove", move);
    window.removeEventListener("mouseup", up);
    const values = fractions();
    if (Math.abs(values[k] - fraction) > 1e-6) {
      values[k] = fraction;
      setFractions(values);
      send();
    } else {
      render();
    }
  };
  window.addEventListener("mousemove", move);
  window.addEventListener("mouseup", up);
}

function addElectrode() {
  const values = fractions().slice().sort((a, b) => a - b);
  let best = 0, at = 0;
  for (let i = 0; i < values.length; i++) {
    const next = i + 1 < values.length ? values[i + 1] : values[0] + 1;
    if (next - values[i] > best) { best = next - values[i]; at = values[i] + best / 2; }
  }
  values.push(at % 1);
  setFractions(values);
  send();
}

function removeElectrode() {
  if (designer.selected < 0) { showError("select an electrode first (click it)"); return; }
  const values = fractions();
  values.splice(designer.selected, 1);
  designer.selected = -1;
  setFractions(values);
  send();
}

function showError(text) {
  $("error").textContent = text;
}

async function send() {
  if (designer.busy) { designer.queued = true; return; }
  designer.busy = true;
  $("status").textContent = "modelling ...";
  const sent = JSON.parse(JSON.stringify(designer.data));
  const model = await post("/api/update", { data: sent, layer_index: designer.layer });
  designer.busy = false;
  if (model.ok) {
    designer.good = sent;
    designer.model = model;
    designer.layer = model.layer_index;
    showError("");
    designer.version += 1;
    render();
  } else {
    showError(model.error);
    designer.data = JSON.parse(JSON.stringify(designer.good));
    designer.version += 1;
    render();
  }
  if (designer.queued) { designer.queued = false; send(); }
}

function show(state) {
  if (!state.model.ok) { showError(state.model.error); return; }
  designer.data = state.data;
  designer.good = JSON.parse(JSON.stringify(state.data));
  designer.model = state.model;
  designer.path = state.path;
  designer.layer = state.model.layer_index;
  designer.selected = -1;
  $("source").textContent = state.path || "(new design: give a path to save)";
  $("save-path").value = state.path || "";
  showError("");
  designer.version += 1;
  render();
}

function wire() {
  for (const [id, options] of [
    ["drive", ["adjacent", "opposite", "trigonometric"]],
    ["measure", ["adjacent", "opposite"]],
  ]) {
    $(id).replaceChildren(...options.map((name) => {
      const o = document.createElement("option");
      o.value = name; o.textContent = name;
      return o;
    }));
  }
  $("add-electrode").onclick = addElectrode;
  $("remove-electrode").onclick = removeElectrode;
  $("width").onchange = () => { layerData().electrodes.width = +$("width").value / 1e3; send(); };
  for (const id of ["drive", "measure"]) {
    $(id).onchange = () => {
      const layer = layerData();
      layer.protocol = Object.assign({}, layer.protocol || {}, { [id]: $(id).value });
      send();
    };
  }
  $("max-edge").onchange = () => {
    const layer = layerData();
    const edge = +$("max-edge").value / 1e3;
    layer.mesh = Object.assign({}, layer.mesh || {});
    layer.mesh.max_edge = edge;
    if (layer.mesh.electrode_edge && layer.mesh.electrode_edge > edge) layer.mesh.electrode_edge = edge;
    if (layer.solver) delete layer.solver.accuracy_target;
    send();
  };
  $("target").onchange = () => {
    const layer = layerData();
    layer.solver = Object.assign({}, layer.solver || {});
    const value = $("target").value;
    if (value === "") {
      delete layer.solver.accuracy_target;
    } else {
      layer.solver.accuracy_target = { position_error_percent: +value };
      for (const key of ["max_edge", "electrode_edge", "inverse_max_edge"]) delete (layer.mesh || {})[key];
      for (const key of ["image_pixels", "max_iterations"]) delete layer.solver[key];
    }
    send();
  };
  $("layer").onchange = () => { designer.layer = +$("layer").value; designer.selected = -1; send(); };
  $("map-kind").onchange = () => renderMap();
  $("remove-holes").onclick = () => { delete layerData().holes; send(); };
  $("sheet").addEventListener("click", (ev) => {
    if (!$("hole-mode").checked || ev.target.classList.contains("electrode")) return;
    const box = $("sheet").getBoundingClientRect();
    const v = designer.view;
    const radius = +$("hole-diameter").value / 2e3;
    const layer = layerData();
    layer.holes = (layer.holes || []).concat([{
      type: "circle",
      center: [+v.x(ev.clientX - box.left).toFixed(6), +v.y(ev.clientY - box.top).toFixed(6)],
      radius,
    }]);
    send();
  });
  $("save").onclick = async () => {
    const answer = await post("/api/save", { path: $("save-path").value });
    designer.lastSave = answer;
    if (answer.ok) {
      designer.path = answer.path;
      $("source").textContent = answer.path;
      $("status").textContent = `saved ${answer.path} (content hash ${answer.content_hash.slice(0, 16)})`;
      showError("");
    } else {
      showError(answer.error);
    }
  };
  $("load").onclick = async () => {
    const state = await post("/api/load", { path: $("save-path").value });
    if (state.ok === false) { showError(state.error); return; }
    show(state);
  };
}

wire();
fetch("/api/design").then((r) => r.json()).then(show);
