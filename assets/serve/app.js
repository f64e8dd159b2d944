// lobe serve: the page's script. Plain JS, no libraries. Every request goes to the server that sent this
// page; POSTs carry X-Lobe-Client (the server refuses POSTs without it: other sites cannot send it).
//
// Data flow: the editor's text compiles (debounced) into the parameter list; the sliders and the incident
// direction are the page's state; every change asks for a live frame at once (parameters live, no
// recompilation), the 3D lobe and the image slice (numbers, drawn here), and — once the controls rest — the
// exact frame (compiled as `lobe render` compiles, byte for byte the CLI's), the numbers, the plot and the
// comparison. Each kind of request has at most one in flight; a change meanwhile is sent when it returns.
// A traced scene (the server answers with X-Lobe-Scene-Spp) refines: live frames at 1 spp and at most
// LIVE_TRACED_SIZE² while the controls move, then exact frames at 1, 4, 16, … spp up to the scene's spp, each
// replacing the last; a change aborts the level in flight and starts over.
"use strict";

const $ = (id) => document.getElementById(id);
const BUILTIN_REFS = [["Blinn: NH^n", "@name \"Blinn\"\nNH^n\n"], ["Phong: VR^n", "@name \"Phong\"\nVR^n\n"]];
const DEFAULT_TEXT = "# a formula in lobe syntax: inputs NL NV NH VR VH, parameter n\nVR^n\n";
const COMPILE_DEBOUNCE_MS = 200;
const REST_MS = 250;
const VIEWS_MS = 200;
const SERVER_SCENE = "\u0000server";
// A traced scene's live frame: one sample per pixel at this side at most (the image is scaled to the chosen
// size): environment.toml's sphere measured 86 ms a frame on two cores at a load of 8 (BENCHMARKS.md §8).
const LIVE_TRACED_SIZE = 128;

// State, exposed as window.lobe for the browser test: frames[] holds the frame times (ms, request to image
// shown) of every completed live render; shown = the settings of the image on screen; views counts the
// redraws of each view; compile_requests counts compiles sent (the editor debounces them).
const lobe = (window.lobe = {
  path: null, hash: null, name: "<page>", loaded: null, text: "", decls: [], params: {}, moved: [], ok: false,
  light: { theta_i: 30, phi_i: 0 }, scene: SERVER_SCENE,
  renders: 0, frames: [], server_ms: [], shown: null, compiles: 0, compile_requests: 0, errors: 0, idle: true,
  // The traced scene's spp (X-Lobe-Scene-Spp; 0: rasterised or not known yet) and the spp of every exact
  // traced frame shown (the refinement, for the browser test).
  scene_spp: 0, levels: [],
  views: { lobe: 0, slice: 0, plot: 0, albedo: 0 }, warnings: [], error_log: [], draw_ms: [],
});

async function api(path, body, signal) {
  const init = body === undefined ? {} : {
    method: "POST", body: JSON.stringify(body), signal,
    headers: { "Content-Type": "application/json", "X-Lobe-Client": "page" },
  };
  const r = await fetch(path, init);
  if (!r.ok) {
    let e;
    try { e = await r.json(); } catch (_) { e = { error: `HTTP ${r.status}` }; }
    e.status = r.status;
    throw e;
  }
  return r;
}

function status(msg, isError) {
  const s = $("status");
  s.textContent = msg || "";
  s.className = isError ? "error" : "";
}

// A refused request (not a formula error, which the diagnostics show; not a busy server, 503, which passes):
// counted for the browser test.
function showError(e) {
  if (e.status !== 503) {
    lobe.errors++;
    lobe.error_log.push(`${e.status || ""} ${e.error}`);
  }
  status(e.error + (e.hint ? ` (${e.hint})` : ""), true);
}

// One kind of request: at most one in flight, the latest wish sent when it returns; a busy server (503: job
// slots full or the deadline passed) gets the same wish again shortly.
function channel(run, onIdle) {
  let busy = false, wish = null;
  const pump = async () => {
    busy = true;
    while (wish !== null) {
      const w = wish;
      wish = null;
      try {
        await run(w);
      } catch (e) {
        if (e && e.name === "AbortError") {
          // Superseded (a refining level the page stopped): the newer wish is already queued.
        } else if (e.status === 503) {
          status(`${e.error}; retrying`);
          if (wish === null) wish = w;
          await new Promise((ok) => setTimeout(ok, 250));
        } else {
          showError(e.error ? e : { error: String(e) });
        }
      }
    }
    busy = false;
    if (onIdle) onIdle();
  };
  return (w) => {
    wish = w;
    if (!busy) pump();
  };
}

// ---- editor with inline diagnostics ----

const escapeHtml = (s) => s.replace(/&/g, "&amp;").replace(/</g, "&lt;").replace(/>/g, "&gt;");

function offsetOf(text, line, col) {
  const lines = text.split("\n");
  let o = 0;
  for (let i = 0; i < line - 1 && i < lines.length; i++) o += lines[i].length + 1;
  return Math.min(text.length, o + col - 1);
}

function showDiagnostics(items) {
  const text = $("editor").value;
  const marks = [];
  const box = $("diag");
  box.textContent = "";
  for (const d of items || []) {
    const div = document.createElement("div");
    div.className = d.severity;
    const where = d.line ? `${d.line}:${d.col}: ` : "";
    div.textContent = `${where}${d.severity}: ${d.message}` + (d.hints || []).map((h) => `\n  help: ${h}`).join("");
    box.appendChild(div);
    if (d.line) {
      const a = offsetOf(text, d.line, d.col);
      let b = offsetOf(text, d.end_line, d.end_col);
      if (b <= a) b = Math.min(text.length, a + 1);
      marks.push([a, Math.max(b, a + 1), d.severity]);
    }
  }
  marks.sort((x, y) => x[0] - y[0]);
  let html = "", at = 0;
  for (const [a, b, sev] of marks) {
    if (a < at) continue;
    html += escapeHtml(text.slice(at, a));
    const inside = text.slice(a, b);
    html += `<mark class="${sev}">${inside === "" || inside === "\n" ? " " : escapeHtml(inside)}</mark>`;
    at = b;
  }
  html += escapeHtml(text.slice(at)) + "\n";
  $("backdrop").innerHTML = html;
  syncScroll();
}

function syncScroll() {
  $("backdrop").scrollTop = $("editor").scrollTop;
}

const dirty = () => lobe.loaded !== null && $("editor").value !== lobe.loaded;

let compileSeq = 0;
// `fresh`: the text is a newly opened file, so every slider starts at the file's declared default.
async function compile(fresh) {
  const seq = ++compileSeq;
  const text = $("editor").value;
  lobe.compile_requests++;
  try {
    const r = await (await api("/api/compile", { name: lobe.name, text })).json();
    if (seq !== compileSeq) return;
    lobe.ok = true;
    lobe.text = text;
    lobe.compiledName = lobe.name;
    lobe.compiles++;
    lobe.warnings = r.warnings;
    showDiagnostics(r.warnings);
    $("simplified").textContent = r.simplified;
    lobe.parse_us = r.parse_us;
    buildSliders(r.params, fresh);
    status(dirty() ? "edited (not saved)" : "");
    changed();
  } catch (e) {
    if (seq !== compileSeq) return;
    lobe.ok = false;
    analyzeSeq++;
    clearNumbers(e.error ? `not analysed: ${e.error}` : "not analysed");
    showDiagnostics(e.diagnostics || []);
    if (!e.diagnostics) showError(e); else status(e.error, true);
  }
}

// ---- sliders (live parameters: no recompilation) ----

function range(p) {
  let lo = typeof p.lo === "number" ? p.lo : NaN, hi = typeof p.hi === "number" ? p.hi : NaN;
  const span = Math.max(1, Math.abs(p.default)) * 10;
  if (!isFinite(lo)) lo = p.default - span;
  if (!isFinite(hi)) hi = p.default + span;
  const whole = [lo, hi, p.default].every(Number.isInteger) && hi - lo <= 5000;
  return { lo, hi, step: whole ? 1 : (hi - lo) / 1000 };
}

// A slider: name, range input, number input; `set(v)` is called with every new value.
function slider(box, id, name, lo, hi, step, v, set) {
  const label = document.createElement("label");
  label.innerHTML = `<span></span><input type="range"><input type="number">`;
  label.children[0].textContent = name;
  label.title = name;
  const [s, num] = [label.children[1], label.children[2]];
  s.id = `slider-${id}`;
  num.id = `value-${id}`;
  for (const el of [s, num]) Object.assign(el, { min: lo, max: hi, step, value: v });
  s.addEventListener("input", () => { num.value = s.value; label.classList.add("moved"); set(+s.value); });
  num.addEventListener("change", () => {
    const x = Math.min(hi, Math.max(lo, +num.value));
    num.value = s.value = x;
    label.classList.add("moved");
    set(x);
  });
  box.appendChild(label);
  return label;
}

// Sliders for the parameters the compiled formula reads (a declared parameter it never reads changes nothing).
// An edit keeps the value of a parameter whose declaration did not change; a fresh file, or a changed
// declaration, starts at the declared default.
function buildSliders(decls, fresh) {
  decls = decls.filter((p) => p.read);
  const sig = (p) => `${p.name}:${p.default}:${p.lo}:${p.hi}`;
  if (!fresh && decls.map(sig).join(",") === lobe.decls.map(sig).join(",")) return;
  const before = new Map(lobe.decls.map((p) => [p.name, sig(p)]));
  const old = lobe.params, oldMoved = lobe.moved;
  lobe.decls = decls;
  lobe.params = {};
  lobe.moved = [];
  const box = $("sliders");
  box.textContent = "";
  if (!decls.length) box.textContent = "(the formula reads no parameter)";
  for (const p of decls) {
    const { lo, hi, step } = range(p);
    const keep = !fresh && before.get(p.name) === sig(p) && old[p.name] !== undefined;
    const v = keep ? old[p.name] : p.default;
    lobe.params[p.name] = v;
    if (keep && oldMoved.includes(p.name)) lobe.moved.push(p.name);
    const label = slider(box, p.name, p.name, lo, hi, step, v, (x) => setParam(p.name, x));
    if (lobe.moved.includes(p.name)) label.classList.add("moved");
  }
}

function setParam(name, v) {
  lobe.params[name] = v;
  if (!lobe.moved.includes(name)) lobe.moved.push(name);
  changed();
}

function buildLight() {
  const box = $("light");
  slider(box, "theta_i", "θᵢ", 0, 89, 1, lobe.light.theta_i, (x) => { lobe.light.theta_i = x; lightChanged(); });
  slider(box, "phi_i", "φᵢ", 0, 360, 1, lobe.light.phi_i, (x) => { lobe.light.phi_i = x; lightChanged(); });
}

// ---- the render: live frames while the controls move, the exact frame when they rest ----

// The formula of every request: the text of the last successful compile, so that it always goes with the
// parameters its compile declared (the editor may already hold the next keystroke or file).
const formula = () => ({ name: lobe.compiledName, text: lobe.text });

// Every frame asks for 1 spp (a rasterised scene ignores it): a live frame of a traced scene is that at a
// small side; an exact one is the first level at the chosen size (the next levels follow when it is shown).
function frameSettings(exact) {
  const s = { ...formula(), path: lobe.path, params: { ...lobe.params }, moved: [...lobe.moved], size: +$("size").value, exact, spp: 1 };
  if (lobe.scene !== SERVER_SCENE) s.scene = lobe.scene;
  if (!exact && lobe.scene_spp) s.size = Math.min(s.size, LIVE_TRACED_SIZE);
  return s;
}

// The level in flight (a traced exact frame), aborted by the next change (the server finishes it or stops it
// at its deadline; the page no longer waits for it). A rasterised scene's exact frame is not aborted.
let refining = null;
let frameUrl = null;
const frames = channel(async (settings) => {
  lobe.idle = false;
  const t0 = performance.now();
  const level = settings.exact && lobe.scene_spp ? new AbortController() : null;
  refining = level;
  let r;
  try {
    r = await api("/api/render", settings, level ? level.signal : undefined);
  } catch (e) {
    // A finer level the server's budget refuses ends the refinement; the coarser image stays.
    if (e.status === 422 && settings.exact && settings.spp > 1) {
      $("frame-info").textContent += ` · refined up to here: ${settings.spp} spp is over the server's budget at ${settings.size}²`;
      return;
    }
    throw e;
  } finally {
    if (refining === level) refining = null;
  }
  const serverMs = r.headers.get("X-Lobe-Render-Ms");
  const nan = r.headers.get("X-Lobe-Nan");
  const sceneSpp = +(r.headers.get("X-Lobe-Scene-Spp") || 0);
  const spp = +(r.headers.get("X-Lobe-Spp") || 0);
  // The scene is known traced (or not) from the reply of its first frame.
  if ((settings.scene === undefined ? SERVER_SCENE : settings.scene) === lobe.scene) lobe.scene_spp = sceneSpp;
  const url = URL.createObjectURL(await r.blob());
  const img = $("frame");
  await new Promise((ok, fail) => { img.onload = ok; img.onerror = fail; img.src = url; });
  const ms = performance.now() - t0;
  if (frameUrl) URL.revokeObjectURL(frameUrl);
  frameUrl = url;
  if (!settings.exact) {
    lobe.frames.push(ms);
    lobe.server_ms.push(+serverMs);
  }
  lobe.renders++;
  lobe.shown = { ...settings, spp: spp || undefined };
  if (settings.exact && spp) lobe.levels.push(spp);
  refreshViews();
  if ($("status").textContent.endsWith("retrying")) status("");
  const refined = spp ? ` · ${spp} of ${sceneSpp} spp` : "";
  $("frame-info").textContent = `${settings.size}² · ${settings.exact ? "exact (as lobe render)" : "live"}${refined} · frame ${ms.toFixed(1)} ms (server ${serverMs} ms)` +
    (nan !== "0" ? ` · warning: ${nan} kernel evaluations returned NaN or ±inf and were shaded as no light` : "");
  // The next level the server names, unless a change came meanwhile (its wish is queued and wins).
  const next = settings.exact && spp ? +(r.headers.get("X-Lobe-Next-Spp") || 0) : 0;
  if (next && settings.generation === generation) frames({ ...settings, spp: next });
}, () => { lobe.idle = true; });

// Counts the changes: a refining level continues only while no change came after it was asked for.
let generation = 0;
function requestFrame(exact) {
  if (!lobe.ok) return;
  lobe.idle = false;
  if (refining) refining.abort();
  frames({ ...frameSettings(exact), generation });
}

// ---- views: 3D lobe and image slice (following the frames), plot, albedo, numbers (when the controls rest) ----

const timers = {};
function later(name, ms, f) {
  clearTimeout(timers[name]);
  timers[name] = setTimeout(f, ms);
}

// The 3D lobe and the slice follow the frames: asked for when a frame is shown (so during a drag they update
// at the frame rate without delaying the frames), and when the controls rest.
// During a drag they are asked for at most every VIEWS_MS: their drawing (two canvases repainted) would
// otherwise land while the next frame is on its way and delay it.
let viewsStale = false, viewsAt = -Infinity;
function refreshViews() {
  if (!viewsStale || !lobe.ok || !$("views-box").open) return;
  const wait = viewsAt + VIEWS_MS - performance.now();
  if (wait > 0) { later("views", wait, refreshViews); return; }
  viewsAt = performance.now();
  viewsStale = false;
  lobeView(viewRequest());
  sliceView({ ...formula(), params: { ...lobe.params }, res: 64 });
}

function changed() {
  generation++;
  viewsStale = true;
  requestFrame(false);
  // One side request at a time, after the controls rest: the frames keep the server's job slots.
  later("side", REST_MS, async () => {
    refreshViews();
    requestFrame(true);
    await analyze();
    await comparePanel();
    await plotPanel();
  });
}

function lightChanged() {
  if (!lobe.ok) return;
  if ($("views-box").open) lobeView(viewRequest());
  drawAlbedo();
  later("plot", REST_MS, plotPanel);
}

const viewRequest = () => ({ ...formula(), params: { ...lobe.params }, theta_i: lobe.light.theta_i, phi_i: lobe.light.phi_i, n_theta: 25, n_phi: 48 });

// The 3D lobe: f over the outgoing hemisphere as a surface of radius f·(direction), drawn with the painter's
// algorithm on a 2D canvas (a few thousand quads), the light and its mirror direction as rays.
const cam = { yaw: -0.6, pitch: 0.45 };
let lobeData = null;
const lobeView = channel(async (req) => {
  lobeData = await (await api("/api/lobe", req)).json();
  drawSoon();
});

// Draws the lobe at the next animation frame (once however many replies or pointer moves came meanwhile).
let drawPending = false;
function drawSoon() {
  if (drawPending) return;
  drawPending = true;
  requestAnimationFrame(() => { drawPending = false; drawLobe(); });
}

function drawLobe() {
  const t0 = performance.now();
  const c = $("lobe3d"), g = c.getContext("2d"), r = lobeData;
  g.fillStyle = "#0f1115";
  g.fillRect(0, 0, c.width, c.height);
  if (!r) return;
  const { n_theta: nt, n_phi: np } = r;
  const max = r.max > 0 ? r.max : 1;
  const [cy, sy, cp, sp] = [Math.cos(cam.yaw), Math.sin(cam.yaw), Math.cos(cam.pitch), Math.sin(cam.pitch)];
  const scale = Math.min(c.width, c.height) * 0.42;
  // World z up; yaw about z, then the eye raised by `pitch` above the surface: the eye is along
  // (0, −cos p, sin p), so `depth` (cos p·y − sin p·z) grows away from it.
  const project = ([x, y, z]) => {
    const x1 = cy * x - sy * y, y1 = sy * x + cy * y;
    const depth = cp * y1 - sp * z, up = sp * y1 + cp * z;
    return [c.width / 2 + scale * x1, c.height * 0.72 - scale * up, depth];
  };
  const dir = (t, p) => [Math.sin(t) * Math.cos(p), Math.sin(t) * Math.sin(p), Math.cos(t)];
  const pts = [];
  for (let i = 0; i < nt; i++) {
    for (let j = 0; j < np; j++) {
      let v = r.values[i * np + j];
      v = typeof v === "number" && isFinite(v) ? Math.max(0, v) / max : 0;
      const d = dir((Math.PI / 2) * i / (nt - 1), (2 * Math.PI * j) / np);
      pts.push({ p: project(d.map((x) => x * v)), v });
    }
  }
  // The surface disc and the normal.
  g.strokeStyle = "#3a3f4b";
  g.beginPath();
  for (let k = 0; k <= 64; k++) {
    const [x, y] = project(dir(Math.PI / 2, (2 * Math.PI * k) / 64));
    if (k) g.lineTo(x, y); else g.moveTo(x, y);
  }
  g.stroke();
  const quads = [];
  for (let i = 0; i + 1 < nt; i++) {
    for (let j = 0; j < np; j++) {
      const q = [pts[i * np + j], pts[i * np + (j + 1) % np], pts[(i + 1) * np + (j + 1) % np], pts[(i + 1) * np + j]];
      quads.push({ q, depth: q.reduce((s, x) => s + x.p[2], 0) / 4, v: q.reduce((s, x) => s + x.v, 0) / 4 });
    }
  }
  quads.sort((a, b) => b.depth - a.depth);
  // Filled quads only (an outline per quad doubles the cost on a software canvas); the colour is the value,
  // darker towards the back so the shape reads.
  for (const { q, v, depth } of quads) {
    const shade = 0.75 + 0.25 * Math.max(-1, Math.min(1, -depth * 1.5));
    const [cr, cg, cb] = heat(0.25 + 0.75 * v).map((x) => Math.round(x * shade));
    g.fillStyle = `rgb(${cr},${cg},${cb})`;
    g.beginPath();
    g.moveTo(q[0].p[0], q[0].p[1]);
    g.lineTo(q[1].p[0], q[1].p[1]);
    g.lineTo(q[2].p[0], q[2].p[1]);
    g.lineTo(q[3].p[0], q[3].p[1]);
    g.fill();
  }
  const ray = (d, colour, dash) => {
    const [x0, y0] = project([0, 0, 0]), [x1, y1] = project(d.map((x) => x * 1.1));
    g.setLineDash(dash);
    g.strokeStyle = colour;
    g.lineWidth = 2;
    g.beginPath();
    g.moveTo(x0, y0);
    g.lineTo(x1, y1);
    g.stroke();
    g.setLineDash([]);
    g.lineWidth = 1;
  };
  const l = r.light;
  ray([0, 0, 1], "#9aa0a6", [2, 3]);
  ray(l, "#ffd54f", []);
  ray([-l[0], -l[1], l[2]], "#ffd54f", [5, 4]);
  lobe.views.lobe++;
  lobe.draw_ms.push(performance.now() - t0);
  $("lobe3d-info").textContent = `3D lobe at θᵢ = ${r.theta_i}°, φᵢ = ${r.phi_i}° · max ${fmt(r.max)}` +
    (r.nonfinite ? ` · ${r.nonfinite} directions NaN/inf` : "") + " · yellow: light, dashed: mirror · drag to rotate";
}

function dragToRotate() {
  const c = $("lobe3d");
  let last = null;
  c.addEventListener("pointerdown", (e) => { last = [e.clientX, e.clientY]; c.setPointerCapture(e.pointerId); });
  c.addEventListener("pointerup", () => { last = null; });
  c.addEventListener("pointermove", (e) => {
    if (!last) return;
    cam.yaw += (e.clientX - last[0]) * 0.01;
    cam.pitch = Math.max(-1.5, Math.min(1.5, cam.pitch + (e.clientY - last[1]) * 0.01));
    last = [e.clientX, e.clientY];
    drawSoon();
  });
}

// The colour ramp of the server's difference heat map (black → red → yellow → white), for the views.
function heat(t) {
  t = (isFinite(t) ? Math.min(1, Math.max(0, t)) : 0) * 3;
  const c = (x) => Math.round(Math.min(1, Math.max(0, x)) * 255);
  return [c(t), c(t - 1), c(t - 2)];
}

// The image slice: f(θ_h, θ_d) as colour (the cube root of f/max, so the lobe's tail shows), below the
// horizon dark blue; a colour bar under it.
const sliceView = channel(async (req) => {
  const r = await (await api("/api/slice", req)).json();
  const c = $("slice"), g = c.getContext("2d");
  c.width = c.height = r.res;
  const img = g.createImageData(r.res, r.res);
  const max = r.max > 0 ? r.max : 1;
  r.values.forEach((v, k) => {
    const rgb = typeof v === "number" ? heat(Math.cbrt(Math.max(0, v) / max)) : [20, 24, 48];
    img.data.set([...rgb, 255], 4 * k);
  });
  g.putImageData(img, 0, 0);
  const bar = $("slice-bar"), bg = bar.getContext("2d");
  for (let x = 0; x < bar.width; x++) {
    const [cr, cg, cb] = heat(x / (bar.width - 1));
    bg.fillStyle = `rgb(${cr},${cg},${cb})`;
    bg.fillRect(x, 0, 1, bar.height);
  }
  lobe.views.slice++;
  $("slice-info").textContent = `image slice θ_h → (0–90°), θ_d ↓ (0–90°), φ_d = ${r.phi_d}° · colour bar: 0 → ${fmt(r.max)} (cube-root scale)`;
});

// ---- slower panels: numbers, albedo, comparison, plot ----

function refText() {
  const v = $("reference").value;
  const b = BUILTIN_REFS.find(([n]) => n === v);
  return b ? Promise.resolve({ name: v, text: b[1] }) : fileText(v);
}

const fileCache = {};
async function fileText(path) {
  if (!fileCache[path]) fileCache[path] = (await api(`/api/file?path=${encodeURIComponent(path)}`)).json();
  const f = await fileCache[path];
  return { name: path, text: f.text };
}

const fmt = (x, d = 4) => (typeof x === "number" ? (Math.abs(x) >= 1e4 || (x !== 0 && Math.abs(x) < 1e-3) ? x.toExponential(3) : x.toFixed(d)) : String(x));

let analyzeSeq = 0, albedoRows = [];
// A failed analysis leaves no number of the previous formula on the page: every cell says the error instead.
function clearNumbers(error) {
  for (const id of ["num-compile", "num-ns", "num-coef", "num-albedo"]) $(id).textContent = "–";
  $("num-error").textContent = error;
  albedoRows = [];
  drawAlbedo(error);
}
async function analyze() {
  if (!lobe.ok) return;
  const seq = ++analyzeSeq;
  try {
    const reference = await refText();
    const r = await (await api("/api/analyze", { ...formula(), params: lobe.params, reference })).json();
    if (seq !== analyzeSeq) return;
    $("num-compile").textContent = `${fmt(r.compile_us, 0)} µs JIT (uncached) + ${fmt(lobe.parse_us, 0)} µs parse/simplify/accuracy pass`;
    $("num-ns").textContent = `${fmt(r.jit_ns, 2)} / ${fmt(r.jit_batch_ns, 2)} / ${fmt(r.interp_ns, 2)}`;
    $("num-coef").textContent = r.coef !== undefined ? fmt(r.coef) : r.coef_error;
    $("num-albedo").textContent = r.albedo_max !== undefined ? `${fmt(r.albedo_max)} at θᵢ = ${r.theta_i_at_max_deg}°` : r.albedo_error;
    // The papers' n-sweep where both read n; else the hemisphere metrics (log, RMSE, cosine-weighted L2).
    const h = r.hemisphere;
    $("num-error").textContent = h
      ? `over the hemisphere (no n to sweep): log ${fmt(h.log, 4)} · RMSE ${fmt(h.rmse, 4)} · cosine ${fmt(h.cosine, 4)}`
      : `mean |Δ| ${fmt(r.mean_abs_grid, 6)} · epicentre ${fmt(r.epicenter_max_rel_pct, 2)} % · max ${fmt(r.max_abs)}`;
    albedoRows = r.albedo || [];
    drawAlbedo(r.albedo_error);
  } catch (e) {
    if (seq === analyzeSeq) clearNumbers(e.error || String(e));
  }
}

// ρ(θᵢ) against θᵢ, with the line ρ = 1 and the current θᵢ marked.
function drawAlbedo(error) {
  const c = $("albedo"), g = c.getContext("2d");
  const [w, h, left, bottom] = [c.width, c.height, 40, 24];
  g.fillStyle = "#0f1115";
  g.fillRect(0, 0, w, h);
  g.font = "11px sans-serif";
  g.fillStyle = "#9aa0a6";
  if (!albedoRows.length) {
    g.fillText(error || "no albedo yet", 8, 20);
    return;
  }
  const top = Math.max(1, ...albedoRows.map((p) => p[1])) * 1.05;
  const X = (t) => left + (t / 90) * (w - left - 8), Y = (v) => h - bottom - (v / top) * (h - bottom - 8);
  g.strokeStyle = "#3a3f4b";
  for (const v of [0, 0.5, 1]) {
    g.beginPath(); g.moveTo(left, Y(v)); g.lineTo(w - 8, Y(v)); g.stroke();
    g.fillText(v.toFixed(1), 8, Y(v) + 4);
  }
  for (const t of [0, 30, 60, 90]) g.fillText(`${t}°`, X(t) - 8, h - 6);
  g.strokeStyle = "#ffd54f";
  g.beginPath(); g.moveTo(X(lobe.light.theta_i), Y(0)); g.lineTo(X(lobe.light.theta_i), Y(top)); g.stroke();
  g.strokeStyle = "#4fc3f7";
  g.lineWidth = 2;
  g.beginPath();
  albedoRows.forEach(([t, v], k) => (k ? g.lineTo(X(t), Y(v)) : g.moveTo(X(t), Y(v))));
  g.stroke();
  g.lineWidth = 1;
  lobe.views.albedo++;
}

async function comparePanel() {
  const on = $("compare-on").checked;
  $("cmp-fig").hidden = !on;
  if (!on || !lobe.ok) return;
  try {
    const b = await fileText($("other").value);
    const s = frameSettings(false);
    const r = await api("/api/compare", { a: formula(), b, path: s.path, params: s.params, moved: s.moved, size: s.size, scene: s.scene });
    const m = JSON.parse(r.headers.get("X-Lobe-Metrics"));
    $("cmp-img").src = URL.createObjectURL(await r.blob());
    $("cmp-info").textContent = `A | B (${b.name}) | |Δgray| · Manhattan ${fmt(m.manhattan)} (covered px ${fmt(m.manhattan_covered)}) · RMSE ${fmt(m.rmse)} · PSNR ${fmt(m.psnr, 2)} dB`;
  } catch (e) {
    showError(e.error ? e : { error: String(e) });
  }
}

async function plotPanel() {
  if (!lobe.ok) return;
  try {
    const formulas = [formula()];
    for (const o of $("overlay").selectedOptions) if (formulas.length < 4) formulas.push(await fileText(o.value));
    if ($("compare-on").checked && formulas.length < 4) formulas.push(await fileText($("other").value));
    const r = await api("/api/plot", { formulas, params: lobe.params, polar: $("polar").checked, theta_i: lobe.light.theta_i, phi_i: lobe.light.phi_i });
    const old = $("plot").src;
    $("plot").src = URL.createObjectURL(await r.blob());
    if (old.startsWith("blob:")) URL.revokeObjectURL(old);
    $("plot-info").textContent = `plane of incidence at θᵢ = ${lobe.light.theta_i}°, φᵢ = ${lobe.light.phi_i}° · ${formulas.length} formula(s)`;
    lobe.views.plot++;
  } catch (e) {
    // A formula with nothing to plot (NaN everywhere) is said under the plot, not counted as a failure.
    if (e.status === 422) { $("plot").removeAttribute("src"); $("plot-info").textContent = `${e.error}${e.hint ? ` (${e.hint})` : ""}`; }
    else showError(e.error ? e : { error: String(e) });
  }
}

// ---- files and scenes ----

// Opens a served formula file; unsaved edits are confirmed first (declining keeps the page as it is).
async function open(path) {
  if (dirty() && !confirm(`Discard the unsaved edits to ${lobe.path}?`)) {
    $("file").value = lobe.path;
    return;
  }
  try {
    const f = await (await api(`/api/file?path=${encodeURIComponent(path)}`)).json();
    Object.assign(lobe, { path, hash: f.hash, name: path, loaded: f.text });
    $("editor").value = f.text;
    $("file").value = path;
    status(`opened ${path}`);
    clearTimeout(timers.compile);
    compile(true);
  } catch (e) {
    $("file").value = lobe.path;
    showError(e);
  }
}

async function save(force) {
  if (!lobe.path) { status("this formula has no file: open one from the list", true); return; }
  try {
    const text = $("editor").value;
    const r = await (await api("/api/save", { path: lobe.path, text, hash: lobe.hash, force: !!force })).json();
    lobe.hash = r.hash;
    lobe.loaded = text;
    delete fileCache[lobe.path];
    status(`saved ${lobe.path}`);
  } catch (e) {
    if (e.status === 409 && confirm(`${e.error}.\n\nOverwrite it with the formula on this page?`)) return save(true);
    showError(e);
  }
}

async function init() {
  const s = await (await api("/api/session")).json();
  const fill = (sel, names) => { for (const n of names) sel.add(new Option(n, n)); };
  fill($("file"), s.files);
  fill($("reference"), BUILTIN_REFS.map(([n]) => n).concat(s.files));
  fill($("other"), s.files);
  fill($("overlay"), s.files);
  const scenes = $("scene");
  scenes.add(new Option(`${s.scene} (as started)`, SERVER_SCENE));
  scenes.add(new Option("paper sphere (built in)", ""));
  fill(scenes, s.scenes);
  const phong = s.files.find((f) => f.endsWith("/phong.brdf"));
  if (phong) $("other").value = phong;
  buildLight();
  dragToRotate();
  const ed = $("editor");
  ed.addEventListener("input", () => { showDiagnostics([]); later("compile", COMPILE_DEBOUNCE_MS, () => compile(false)); });
  ed.addEventListener("scroll", syncScroll);
  $("file").addEventListener("change", () => open($("file").value));
  $("scene").addEventListener("change", () => { lobe.scene = $("scene").value; lobe.scene_spp = 0; changed(); });
  $("save").addEventListener("click", () => save(false));
  $("size").addEventListener("change", () => { $("frame").style.width = $("frame").style.height = `${$("size").value}px`; changed(); });
  for (const id of ["compare-on", "other"]) $(id).addEventListener("change", () => { comparePanel(); plotPanel(); });
  for (const id of ["polar", "overlay"]) $(id).addEventListener("change", plotPanel);
  $("views-box").addEventListener("toggle", () => { if ($("views-box").open) { viewsStale = true; refreshViews(); plotPanel(); } });
  $("reference").addEventListener("change", analyze);
  window.addEventListener("beforeunload", (e) => { if (dirty()) e.preventDefault(); });
  const first = s.open || s.files.find((f) => f.endsWith("modified_schlick_vr.brdf")) || s.files[0];
  if (first) open(first);
  else { ed.value = DEFAULT_TEXT; compile(true); }
}

init().catch(showError);
