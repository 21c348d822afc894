// econdor: the page of a live run (econdor run --web) or a replay (econdor view).
// One WebSocket (/ws) brings JSON messages (see econdor_gcs/web/__init__.py); the map is
// three stacked canvases (estimate, sample paths, pieces + vehicles), curves are uPlot.
"use strict";

const PHASE_COLOURS = { transit: "#b0b7c0", search: "#00e5ff", trace: "#ff4081", survey: "#ffffff" };
const VEHICLE_COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
                         "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"];
const MAX_LOG_LINES = 600;

const $ = (id) => document.getElementById(id);
const vcolour = (i) => VEHICLE_COLOURS[i % VEHICLE_COLOURS.length];

const state = {
  hello: null,
  records: [],            // per iteration, in order
  frames: new Map(),      // iteration -> frame message
  plan: null,             // pieces of the iteration being flown (live)
  samples: { n: 0, x: new Float32Array(0), y: new Float32Array(0),
             phase: new Uint8Array(0), vehicle: new Uint8Array(0) },
  trail: { n: 0, x: new Float32Array(0), y: new Float32Array(0),
           phase: new Uint8Array(0), vehicle: new Uint8Array(0) },
  vehicles: [],           // latest snapshot (live)
  logs: [],
  control: null,          // {state, iteration}
  done: null,
  view: -1,               // iteration shown
  follow: true,
  phaseNames: {},         // code -> name
  ws: null,
};

// -- decoding ---------------------------------------------------------------------------------
function bytes(b64) {
  const s = atob(b64);
  const out = new Uint8Array(s.length);
  for (let i = 0; i < s.length; i++) out[i] = s.charCodeAt(i);
  return out;
}
const f32 = (b64) => new Float32Array(bytes(b64).buffer);
const u8 = (b64) => bytes(b64);

function concat(Kind, a, b) {
  const out = new Kind(a.length + b.length);
  out.set(a, 0); out.set(b, a.length);
  return out;
}
function appendColumns(store, msg) {
  store.x = concat(Float32Array, store.x, f32(msg.x));
  store.y = concat(Float32Array, store.y, f32(msg.y));
  store.phase = concat(Uint8Array, store.phase, u8(msg.phase));
  store.vehicle = concat(Uint8Array, store.vehicle, u8(msg.vehicle));
  store.n = store.x.length;
}

// -- geometry -----------------------------------------------------------------------------------
const PAD = 14;
function mapBox(canvas) {
  const r = state.hello.region;
  const W = canvas.width - 2 * PAD, H = canvas.height - 2 * PAD;
  const s = Math.min(W / (r.xmax - r.xmin), H / (r.ymax - r.ymin));
  const w = s * (r.xmax - r.xmin), h = s * (r.ymax - r.ymin);
  const ox = PAD + (W - w) / 2, oy = PAD + (H - h) / 2;
  return { s, ox, oy, w, h,
           px: (x) => ox + (x - r.xmin) * s,
           py: (y) => oy + (r.ymax - y) * s };
}
function sizeCanvases() {
  // true when the canvases were resized (and so cleared)
  const dpr = window.devicePixelRatio || 1;
  let resized = false;
  for (const id of ["estimate", "paths", "overlay"]) {
    const c = $(id);
    const w = Math.round(c.clientWidth * dpr), h = Math.round(c.clientHeight * dpr);
    if (c.width !== w || c.height !== h) { c.width = w; c.height = h; resized = true; }
  }
  return resized;
}

// -- the estimate -------------------------------------------------------------------------------
function drawEstimate(frame) {
  const c = $("estimate"), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  if (!frame) { c.dataset.iteration = ""; return; }
  const b = mapBox(c);
  const v = f32(frame.estimate);
  const lut = state.hello.colormap;
  const img = new ImageData(frame.nx, frame.ny);
  const span = frame.max - frame.min || 1;
  for (let r = 0; r < frame.ny; r++) {
    const dst = (frame.ny - 1 - r) * frame.nx;  // row 0 is the southern edge
    for (let k = 0; k < frame.nx; k++) {
      const t = Math.max(0, Math.min(255, Math.round(((v[r * frame.nx + k] - frame.min) / span) * 255)));
      const rgb = lut[t], o = (dst + k) * 4;
      img.data[o] = rgb[0]; img.data[o + 1] = rgb[1]; img.data[o + 2] = rgb[2]; img.data[o + 3] = 255;
    }
  }
  const off = document.createElement("canvas");
  off.width = frame.nx; off.height = frame.ny;
  off.getContext("2d").putImageData(img, 0, 0);
  g.imageSmoothingEnabled = true;
  g.drawImage(off, b.px(frame.x0), b.py(frame.y1), (frame.x1 - frame.x0) * b.s, (frame.y1 - frame.y0) * b.s);
  g.lineWidth = 1;
  g.strokeStyle = "rgba(255,255,255,0.55)";
  for (const c0 of frame.contours) {
    for (const p of c0.paths) {
      g.beginPath();
      for (let i = 0; i < p.length; i += 2) {
        const X = b.px(p[i]), Y = b.py(p[i + 1]);
        if (i === 0) g.moveTo(X, Y); else g.lineTo(X, Y);
      }
      g.stroke();
    }
  }
  c.dataset.iteration = String(frame.iteration);
  $("cb-min").textContent = frame.min.toFixed(1);
  $("cb-max").textContent = frame.max.toFixed(1);
}

function drawColourbar() {
  const c = $("colorbar"), g = c.getContext("2d");
  const lut = state.hello.colormap;
  for (let i = 0; i < 256; i++) {
    g.fillStyle = `rgb(${lut[i][0]},${lut[i][1]},${lut[i][2]})`;
    g.fillRect(i, 0, 1, c.height);
  }
}

// -- sample paths -------------------------------------------------------------------------------
function strokeColumns(g, b, cols, n, alpha) {
  // each vehicle's samples joined in order (vehicles interleave in the arrays), each
  // segment in the phase of its end
  const byPhase = new Map(), last = new Map();
  for (let i = 0; i < n; i++) {
    const v = cols.vehicle[i], j = last.get(v);
    last.set(v, i);
    if (j === undefined) continue;
    const p = cols.phase[i];
    if (!byPhase.has(p)) byPhase.set(p, []);
    byPhase.get(p).push(j, i);
  }
  g.globalAlpha = alpha;
  g.lineWidth = 1.6 * (window.devicePixelRatio || 1);
  for (const [p, idx] of byPhase) {
    g.strokeStyle = PHASE_COLOURS[state.phaseNames[p]] || "#000";
    g.beginPath();
    for (let k = 0; k < idx.length; k += 2) {
      g.moveTo(b.px(cols.x[idx[k]]), b.py(cols.y[idx[k]]));
      g.lineTo(b.px(cols.x[idx[k + 1]]), b.py(cols.y[idx[k + 1]]));
    }
    g.stroke();
  }
  g.globalAlpha = 1;
}

function samplesShown() {
  // rows of the accounted samples up to the iteration on view (all of them at the last one)
  const last = state.records.length ? state.records[state.records.length - 1].iteration : -1;
  if (state.view < 0 || state.view >= last) return state.samples.n;
  const rec = state.records.find((r) => r.iteration === state.view);
  return rec && rec.samples != null ? Math.min(rec.samples, state.samples.n) : state.samples.n;
}

function drawPaths() {
  const c = $("paths"), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  if (!state.hello) return;
  const b = mapBox(c);
  strokeColumns(g, b, state.samples, samplesShown(), 0.9);
  if (following()) strokeColumns(g, b, state.trail, state.trail.n, 0.9);
}

// -- pieces and vehicles ------------------------------------------------------------------------
function following() { return state.hello && state.hello.mode === "live" && state.follow; }

function piecesOnView() {
  // live and following: the iteration being flown; otherwise what the shown iteration flew
  if (following() && state.plan && state.plan.iteration > lastIteration()) {
    return { iteration: state.plan.iteration, pieces: state.plan.pieces, flying: true };
  }
  const f = state.frames.get(state.view);
  return f ? { iteration: f.iteration, pieces: f.pieces, flying: false } : null;
}

function vehiclesOnView() {
  if (following() && state.vehicles.length) return state.vehicles;
  // a replay (or a look back): where each vehicle's last sample up to that iteration was
  const n = samplesShown(), out = new Map();
  const s = state.samples;
  for (let i = 0; i < n; i++) {
    const k = s.vehicle[i];
    const prev = out.get(k);
    let heading = prev ? prev.heading_deg : null;
    if (prev) {
      const dx = s.x[i] - prev.x_m, dy = s.y[i] - prev.y_m;
      if (dx * dx + dy * dy > 1e-4) heading = (Math.atan2(dx, dy) * 180 / Math.PI + 360) % 360;
    }
    out.set(k, { index: k, sysid: (state.hello.sysids[k] ?? k + 1), x_m: s.x[i], y_m: s.y[i],
                 heading_deg: heading, status: "", phase: state.phaseNames[s.phase[i]],
                 flown_m: (prev ? prev.flown_m + Math.hypot(s.x[i] - prev.x_m, s.y[i] - prev.y_m) : 0),
                 samples: (prev ? prev.samples : 0) + 1, replay: true });
  }
  return [...out.values()].sort((a, b2) => a.index - b2.index);
}

function drawOverlay() {
  const c = $("overlay"), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  if (!state.hello) return;
  const b = mapBox(c), dpr = window.devicePixelRatio || 1;
  g.strokeStyle = "#444"; g.lineWidth = 1;
  g.strokeRect(b.ox, b.oy, b.w, b.h);
  const view = piecesOnView();
  if (view) {
    g.setLineDash([6 * dpr, 4 * dpr]);
    g.lineWidth = 2.2 * dpr;
    g.font = `${10 * dpr}px system-ui, sans-serif`;
    for (const p of view.pieces) {
      g.strokeStyle = vcolour(p.vehicle);
      g.beginPath();
      for (let i = 0; i < p.points.length; i += 2) {
        const X = b.px(p.points[i]), Y = b.py(p.points[i + 1]);
        if (i === 0) g.moveTo(X, Y); else g.lineTo(X, Y);
      }
      g.stroke();
      if (p.piece_id >= 0 && p.points.length >= 2) {
        const m = 2 * Math.floor(p.points.length / 4);
        g.fillStyle = vcolour(p.vehicle);
        g.fillText(String(p.piece_id), b.px(p.points[m]) + 3, b.py(p.points[m + 1]) - 3);
      }
    }
    g.setLineDash([]);
  }
  for (const v of vehiclesOnView()) {
    if (v.x_m == null || v.y_m == null) continue;
    const X = b.px(v.x_m), Y = b.py(v.y_m), r = 7 * dpr;
    g.save();
    g.translate(X, Y);
    g.rotate(((v.heading_deg ?? 0) * Math.PI) / 180);  // from north, clockwise
    g.beginPath();
    g.moveTo(0, -r * 1.4); g.lineTo(r, r); g.lineTo(0, r * 0.45); g.lineTo(-r, r); g.closePath();
    g.fillStyle = vcolour(v.index); g.fill();
    g.lineWidth = 1.2 * dpr; g.strokeStyle = "#000"; g.stroke();
    g.restore();
    g.fillStyle = "#000";
    g.font = `bold ${11 * dpr}px system-ui, sans-serif`;
    g.fillText(String(v.sysid), X + r + 2, Y + r);
  }
}

// -- tables, curves, log ------------------------------------------------------------------------
function fmt(v, digits = 1) { return v == null || Number.isNaN(v) ? "–" : Number(v).toFixed(digits); }
function clock(s) {
  if (s == null) return "–";
  const m = Math.floor(s / 60), r = Math.floor(s % 60);
  return `${m}:${String(r).padStart(2, "0")}`;
}
function cell(tr, text, cls) {
  const td = document.createElement("td");
  td.textContent = text;
  if (cls) td.className = cls;
  tr.appendChild(td);
  return td;
}

function renderVehicles() {
  const body = $("vehicles").querySelector("tbody");
  body.textContent = "";
  // while an iteration flies, each vehicle's pieces come from the plan the pieces table shows
  // (a new plan can arrive before the vehicles' next state does)
  const view = piecesOnView();
  const flying = view && view.flying ? view.pieces : null;
  for (const v of vehiclesOnView()) {
    const tr = document.createElement("tr");
    tr.dataset.sysid = String(v.sysid);
    if (v.lost) tr.className = "lost";
    const name = cell(tr, "");
    const dot = document.createElement("span");
    dot.className = "dot"; dot.style.background = vcolour(v.index);
    name.append(dot, String(v.sysid));
    cell(tr, v.replay ? "(replay)" : (v.lost ? "LOST" : v.status), "status");
    cell(tr, v.phase || "–", "phase");
    cell(tr, fmt(v.x_m), "num x");
    cell(tr, fmt(v.y_m), "num y");
    cell(tr, v.heading_deg == null ? "–" : `${fmt(v.heading_deg, 0)}°`, "num heading");
    cell(tr, v.replay ? "–" : fmt(v.alt_rel_m), "num alt");
    cell(tr, v.replay ? "–" : clock(v.flight_time_s), "num flight-time");
    cell(tr, fmt(v.flown_m, 0), "num flown");
    cell(tr, v.replay ? "–" : `${v.item}/${v.items}`, "num item");
    const mine = flying ? flying.filter(p => p.vehicle === v.index && p.piece_id >= 0)
      .map(p => p.piece_id) : (v.pieces || []);
    cell(tr, mine.join(", "), "pieces");
    body.appendChild(tr);
  }
}

function renderPieces() {
  const view = piecesOnView();
  const body = $("pieces").querySelector("tbody");
  body.textContent = "";
  if (!view) { $("pieces-title").textContent = ""; return; }
  $("pieces-title").textContent = `· iteration ${view.iteration}${view.flying ? " (flying)" : ""} · ${view.pieces.length}`;
  for (const p of view.pieces) {
    const tr = document.createElement("tr");
    const sysid = state.hello.sysids[p.vehicle] ?? p.vehicle + 1;
    const name = cell(tr, "");
    const dot = document.createElement("span");
    dot.className = "dot"; dot.style.background = vcolour(p.vehicle);
    name.append(dot, String(sysid));
    cell(tr, p.piece_id >= 0 ? String(p.piece_id) : "waypoints");
    cell(tr, fmt(p.level, 2), "num");
    cell(tr, String(p.points.length / 2), "num");
    body.appendChild(tr);
  }
}

const charts = [];
function chartSpan() {
  return Math.max(lastIteration(), state.hello && state.hello.max_iterations ? state.hello.max_iterations : 0);
}
function markerPlugin() {
  return { hooks: { draw: [(u) => {
    if (state.view < 0) return;
    const X = u.valToPos(state.view, "x", true);
    const g = u.ctx;
    g.save(); g.strokeStyle = "#c62828"; g.lineWidth = 1;
    g.beginPath(); g.moveTo(X, u.bbox.top); g.lineTo(X, u.bbox.top + u.bbox.height); g.stroke();
    g.restore();
  }] } };
}
function makeCharts() {
  const box = $("charts");
  box.textContent = "";
  charts.length = 0;
  const specs = [];
  if (state.hello.truth_known) specs.push({ title: "MAE (dB)", series: [["MAE dB", "mae_db", "#1f6feb"]] });
  specs.push({ title: "learning error", series: [["learning error", "learning_error", "#2ca02c"]] });
  specs.push({ title: "κ and δ", series: [["κ", "kappa", "#9467bd"], ["δ", "delta", "#ff7f0e"]] });
  specs.push({ title: "distance (m)", series: [["flown", "flight_distance_m", "#d62728"],
                                              ["contour", "contour_distance_m", "#8c564b"]] });
  const width = Math.max(200, Math.floor(box.clientWidth / 2) - 6);
  for (const spec of specs) {
    const div = document.createElement("div");
    div.className = "chart";
    box.appendChild(div);
    const opts = {
      title: spec.title, width, height: 150,
      scales: { x: { time: false, range: (u, lo, hi) => [0, Math.max(1, hi, chartSpan())] } },
      legend: { live: false },
      axes: [{ label: "", size: 28 }, { size: 48 }],
      series: [{ label: "iteration" }, ...spec.series.map(([label, , colour]) =>
        ({ label, stroke: colour, width: 1.5, points: { show: true, size: 5 } }))],
      plugins: [markerPlugin()],
    };
    const u = new uPlot(opts, [[]].concat(spec.series.map(() => [])), div);
    charts.push({ u, spec });
  }
}
function renderCharts() {
  const xs = state.records.map((r) => r.iteration);
  for (const { u, spec } of charts) {
    u.setData([xs, ...spec.series.map(([, key]) => state.records.map((r) => r[key] ?? null))]);
  }
}

function renderLog() {
  const box = $("log");
  const atEnd = box.scrollTop + box.clientHeight >= box.scrollHeight - 4;
  box.textContent = "";
  const lines = following() || state.view < 0 ? state.logs
    : state.logs.filter((ln) => ln.iteration <= state.view);
  for (const ln of lines.slice(-MAX_LOG_LINES)) {
    const div = document.createElement("div");
    div.className = `line ${ln.severity}`;
    const t = document.createElement("span"); t.className = "t"; t.textContent = `${ln.wall_s.toFixed(1).padStart(7)} s `;
    const it = document.createElement("span"); it.className = "t"; it.textContent = `#${ln.iteration} `;
    const src = document.createElement("span"); src.className = "src"; src.textContent = `${ln.source}: `;
    div.append(t, it, src, ln.text);
    box.appendChild(div);
  }
  if (atEnd) box.scrollTop = box.scrollHeight;
}

// -- the run's state and the controls -----------------------------------------------------------
function lastIteration() { return state.records.length ? state.records[state.records.length - 1].iteration : -1; }

function renderStatus() {
  const el = $("run-state");
  let word = state.hello ? (state.hello.mode === "live" ? "running" : "replay") : "connecting";
  if (state.control) word = state.control.state;
  if (state.done) word = state.done.summary.error ? `failed: ${state.done.summary.error}`
    : (state.control && state.control.state === "stopped" ? "stopped" : `finished (${state.done.summary.stop_reason ?? "?"})`);
  el.textContent = word;
  el.className = `state ${state.done && !(state.control && state.control.state === "stopped") ? "finished" : (state.control ? state.control.state : "")}`;
  $("iteration").textContent = state.view >= 0 ? String(state.view) : "–";
  const flying = following() && !state.done && state.plan && state.plan.iteration > lastIteration();
  $("flying").textContent = flying ? `· flying iteration ${state.plan.iteration}` : "";
  const live = state.hello && state.hello.controls && !state.done;
  const s = state.control ? state.control.state : "running";
  $("btn-pause").disabled = !live || s !== "running";
  $("btn-resume").disabled = !live || !(s === "pausing" || s === "paused");
  $("btn-stop").disabled = !live || !(s === "running" || s === "pausing" || s === "paused");
}

const CONFIRM = {
  pause: "Pause after the current iteration? The vehicles finish what they are flying, then hover until you resume.",
  resume: "Resume the run?",
  stop: "Stop the run? The flight in progress ends now: every vehicle returns to launch and lands.",
};
function askControl(action) {
  const dlg = $("confirm");
  $("confirm-text").textContent = CONFIRM[action];
  $("confirm-ok").textContent = action[0].toUpperCase() + action.slice(1);
  dlg.returnValue = "";
  dlg.onclose = () => {
    if (dlg.returnValue === "ok") send({ type: "control", action });
  };
  dlg.showModal();
}

// -- the slider ---------------------------------------------------------------------------------
function updateSlider() {
  const s = $("slider"), last = lastIteration();
  s.max = String(Math.max(0, last));
  s.disabled = last < 0;
  if (following() || (state.hello && state.hello.mode !== "live" && state.view < 0)) setView(last, false);
  s.value = String(Math.max(0, state.view));
  $("slider-value").textContent = state.view >= 0 ? String(state.view) : "–";
}
function setView(iteration, fromUser) {
  if (iteration < 0) return;
  state.view = iteration;
  if (fromUser && state.hello.mode === "live") {
    state.follow = iteration >= lastIteration();
    $("follow").checked = state.follow;
  }
  if (!state.frames.has(iteration)) send({ type: "seek", iteration });
  scheduleRender(ALL);
}

// -- messages -----------------------------------------------------------------------------------
// what a message changes on the page (each part is redrawn only when it changed)
const ALL = ["estimate", "paths", "overlay", "vehicles", "pieces", "log", "status", "charts"];
const TOUCHES = {
  hello: ALL, records: ["charts", "status", "paths", "overlay", "pieces", "vehicles", "log"],
  frame: ["estimate", "overlay", "pieces"], plan: ["overlay", "pieces", "status", "vehicles"],
  samples: ["paths", "overlay", "vehicles"], trail: ["paths"], vehicles: ["overlay", "vehicles"],
  log: ["log"], control: ["status"], done: ["status", "overlay", "pieces", "paths"], error: ["log"],
};
const dirty = new Set();

function onMessage(m) {
  for (const part of TOUCHES[m.type] || []) dirty.add(part);
  switch (m.type) {
    case "hello":
      state.hello = m;
      state.phaseNames = Object.fromEntries(Object.entries(m.phases).map(([k, v]) => [v, k]));
      $("mode").textContent = m.mode === "live" ? "· live" : "· replay";
      $("title").textContent = `${m.mission} · ${m.planner}${m.run_dir ? " · " + m.run_dir : ""}`;
      $("controls").hidden = !m.controls;
      $("follow-label").hidden = m.mode !== "live";
      $("phase-legend").textContent = "";
      for (const [name] of Object.entries(m.phases)) {
        const span = document.createElement("span");
        const sw = document.createElement("span");
        sw.className = "swatch"; sw.style.background = PHASE_COLOURS[name] || "#000";
        span.append(sw, name);
        $("phase-legend").appendChild(span);
      }
      drawColourbar();
      makeCharts();
      break;
    case "records": state.records.push(...m.records); renderCharts(); updateSlider(); break;
    case "frame": state.frames.set(m.iteration, m); break;
    case "plan": state.plan = m; break;
    case "samples": appendColumns(state.samples, m); break;
    case "trail":
      if (m.reset) state.trail = { n: 0, x: new Float32Array(0), y: new Float32Array(0),
                                   phase: new Uint8Array(0), vehicle: new Uint8Array(0) };
      appendColumns(state.trail, m);
      break;
    case "vehicles": state.vehicles = m.vehicles; break;
    case "log": state.logs.push(...m.lines); if (state.logs.length > 5 * MAX_LOG_LINES) state.logs.splice(0, state.logs.length - 5 * MAX_LOG_LINES); break;
    case "control": state.control = m; break;
    case "done": state.done = m; break;
    case "error": logLocal(m.text, "error"); break;
    default: break;
  }
}
function logLocal(text, severity) {
  state.logs.push({ wall_s: performance.now() / 1000, iteration: Math.max(0, state.view),
                    source: "page", severity, text });
}

let scheduled = false;
function renderAll() {
  if (!state.hello) return;
  if (sizeCanvases()) for (const part of ALL) dirty.add(part);
  const f = state.frames.get(state.view);
  if (dirty.has("estimate") || $("estimate").dataset.iteration !== String(f ? f.iteration : "")) {
    drawEstimate(f || null);
  }
  if (dirty.has("paths")) drawPaths();
  if (dirty.has("overlay")) drawOverlay();
  if (dirty.has("vehicles")) renderVehicles();
  if (dirty.has("pieces")) renderPieces();
  if (dirty.has("log")) renderLog();
  if (dirty.has("status")) renderStatus();
  if (dirty.has("charts")) for (const { u } of charts) u.redraw(false);
  dirty.clear();
  $("slider-value").textContent = state.view >= 0 ? String(state.view) : "–";
}
function scheduleRender(parts) {
  for (const part of parts || []) dirty.add(part);
  if (scheduled) return;
  scheduled = true;
  requestAnimationFrame(() => { scheduled = false; renderAll(); });
}

function send(obj) {
  if (state.ws && state.ws.readyState === WebSocket.OPEN) state.ws.send(JSON.stringify(obj));
}

function connect() {
  const token = new URLSearchParams(location.search).get("token");
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  const ws = new WebSocket(`${proto}//${location.host}/ws${token ? "?token=" + encodeURIComponent(token) : ""}`);
  state.ws = ws;
  ws.onopen = () => { $("connection").textContent = "connected"; $("connection").className = "conn"; };
  ws.onmessage = (ev) => { onMessage(JSON.parse(ev.data)); scheduleRender(); };
  ws.onclose = (ev) => {
    $("connection").textContent = state.done ? "server closed (run over)" : `disconnected${ev.reason ? ": " + ev.reason : ""}`;
    $("connection").className = state.done ? "conn" : "conn lost";
  };
}

window.addEventListener("DOMContentLoaded", () => {
  $("slider").addEventListener("input", (e) => setView(Number(e.target.value), true));
  $("follow").addEventListener("change", (e) => {
    state.follow = e.target.checked;
    if (state.follow) setView(lastIteration(), false); else scheduleRender(ALL);
  });
  $("btn-pause").addEventListener("click", () => askControl("pause"));
  $("btn-resume").addEventListener("click", () => askControl("resume"));
  $("btn-stop").addEventListener("click", () => askControl("stop"));
  window.addEventListener("resize", () => scheduleRender(ALL));
  connect();
});
