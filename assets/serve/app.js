// lobe serve: the page's script. Plain JS, no libraries. Every request goes to the server that sent this
// page; POSTs carry X-Lobe-Client (the server refuses POSTs without it: other sites cannot send it).
"use strict";

const $ = (id) => document.getElementById(id);
const BUILTIN_REFS = [["Blinn: NH^n", "@name \"Blinn\"\nNH^n\n"], ["Phong: VR^n", "@name \"Phong\"\nVR^n\n"]];
const DEFAULT_TEXT = "# a formula in lobe syntax: inputs NL NV NH VR VH, parameter n\nVR^n\n";

// State, exposed as window.lobe for the browser test: frames[] holds the frame times (ms, request to image
// shown) of every completed render; shown = the settings of the image on screen.
const lobe = (window.lobe = {
  path: null, hash: null, name: "<page>", decls: [], params: {}, ok: false,
  renders: 0, frames: [], server_ms: [], shown: null, compiles: 0, errors: 0, idle: true,
});

async function api(path, body) {
  const init = body === undefined ? {} : {
    method: "POST", body: JSON.stringify(body),
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
  if (e.status !== 503) lobe.errors++;
  status(e.error + (e.hint ? ` (${e.hint})` : ""), true);
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

let compileSeq = 0;
async function compile() {
  const seq = ++compileSeq;
  const text = $("editor").value;
  try {
    const r = await (await api("/api/compile", { name: lobe.name, text })).json();
    if (seq !== compileSeq) return;
    lobe.ok = true;
    lobe.compiles++;
    showDiagnostics(r.warnings);
    $("simplified").textContent = r.simplified;
    lobe.parse_us = r.parse_us;
    buildSliders(r.params);
    status("");
    changed();
  } catch (e) {
    if (seq !== compileSeq) return;
    lobe.ok = false;
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

function buildSliders(decls) {
  const key = (ds) => ds.map((p) => `${p.name}:${p.lo}:${p.hi}`).join(",");
  const old = lobe.params;
  if (key(decls) === key(lobe.decls)) return;
  lobe.decls = decls;
  lobe.params = {};
  const box = $("sliders");
  box.textContent = "";
  for (const p of decls) {
    const { lo, hi, step } = range(p);
    const v = old[p.name] !== undefined && old[p.name] >= lo && old[p.name] <= hi ? old[p.name] : p.default;
    lobe.params[p.name] = v;
    const label = document.createElement("label");
    label.innerHTML = `<span></span><input type="range"><input type="number">`;
    label.children[0].textContent = p.name;
    const [s, num] = [label.children[1], label.children[2]];
    s.id = `slider-${p.name}`;
    num.id = `value-${p.name}`;
    for (const el of [s, num]) Object.assign(el, { min: lo, max: hi, step, value: v });
    s.addEventListener("input", () => { num.value = s.value; setParam(p.name, +s.value); });
    num.addEventListener("change", () => {
      const x = Math.min(hi, Math.max(lo, +num.value));
      num.value = s.value = x;
      setParam(p.name, x);
    });
    box.appendChild(label);
  }
}

function setParam(name, v) {
  lobe.params[name] = v;
  changed();
}

// ---- frames: at most one render in flight; a change meanwhile is sent when it returns ----

let inFlight = false, pending = false, frameUrl = null, retryAfter = 0;
function requestFrame() {
  if (!lobe.ok) return;
  if (inFlight) { pending = true; lobe.idle = false; return; }
  inFlight = true;
  pending = false;
  lobe.idle = false;
  const settings = { name: lobe.name, text: $("editor").value, params: { ...lobe.params }, size: +$("size").value };
  const t0 = performance.now();
  api("/api/render", settings)
    .then(async (r) => {
      const serverMs = r.headers.get("X-Lobe-Render-Ms");
      const nan = r.headers.get("X-Lobe-Nan");
      const url = URL.createObjectURL(await r.blob());
      const img = $("frame");
      await new Promise((ok, fail) => { img.onload = ok; img.onerror = fail; img.src = url; });
      const ms = performance.now() - t0;
      if (frameUrl) URL.revokeObjectURL(frameUrl);
      frameUrl = url;
      lobe.frames.push(ms);
      lobe.server_ms.push(+serverMs);
      lobe.renders++;
      lobe.shown = settings;
      $("frame-info").textContent = `${settings.size}² · frame ${ms.toFixed(1)} ms (server ${serverMs} ms)` +
        (nan !== "0" ? ` · ${nan} NaN/inf shaded as no light` : "");
    })
    .catch((e) => {
      // A busy server (503: job slots full or the deadline passed) gets the frame again shortly; the
      // status line says so without counting it as an error.
      if (e.status === 503) { status(`${e.error}; retrying`); pending = true; retryAfter = 250; }
      else showError(e.error ? e : { error: String(e) });
    })
    .finally(() => {
      inFlight = false;
      const wait = retryAfter;
      retryAfter = 0;
      if (pending) setTimeout(requestFrame, wait);
      else lobe.idle = true;
    });
}

// ---- slower panels: numbers, comparison, plot (debounced) ----

const timers = {};
function later(name, ms, f) {
  clearTimeout(timers[name]);
  timers[name] = setTimeout(f, ms);
}

function changed() {
  requestFrame();
  // One side request at a time, after the sliders rest: the frames keep the server's job slots.
  later("side", 250, async () => { await analyze(); await comparePanel(); await plotPanel(); });
}

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

let analyzeSeq = 0;
async function analyze() {
  if (!lobe.ok) return;
  const seq = ++analyzeSeq;
  try {
    const reference = await refText();
    const r = await (await api("/api/analyze", { name: lobe.name, text: $("editor").value, params: lobe.params, reference })).json();
    if (seq !== analyzeSeq) return;
    $("num-compile").textContent = `${fmt(r.compile_us, 0)} µs JIT (uncached) + ${fmt(lobe.parse_us, 0)} µs parse/simplify`;
    $("num-ns").textContent = `${fmt(r.jit_ns, 2)} / ${fmt(r.jit_batch_ns, 2)} / ${fmt(r.interp_ns, 2)}`;
    $("num-coef").textContent = r.coef !== undefined ? fmt(r.coef) : r.coef_error;
    $("num-albedo").textContent = r.albedo_max !== undefined ? `${fmt(r.albedo_max)} at θᵢ = ${r.theta_i_at_max_deg}°` : r.albedo_error;
    $("num-error").textContent = `mean |Δ| ${fmt(r.mean_abs_grid, 6)} · epicentre ${fmt(r.epicenter_max_rel_pct, 2)} % · max ${fmt(r.max_abs)}`;
  } catch (e) {
    if (seq === analyzeSeq) $("num-error").textContent = e.error || String(e);
  }
}

async function comparePanel() {
  const on = $("compare-on").checked;
  $("cmp-fig").hidden = !on;
  if (!on || !lobe.ok) return;
  try {
    const b = await fileText($("other").value);
    const r = await api("/api/compare", { a: { name: lobe.name, text: $("editor").value }, b, params: lobe.params, size: +$("size").value });
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
    const formulas = [{ name: lobe.name, text: $("editor").value }];
    if ($("compare-on").checked) formulas.push(await fileText($("other").value));
    const r = await api("/api/plot", { formulas, params: lobe.params, polar: $("polar").checked });
    const old = $("plot").src;
    $("plot").src = URL.createObjectURL(await r.blob());
    if (old.startsWith("blob:")) URL.revokeObjectURL(old);
  } catch (e) {
    showError(e.error ? e : { error: String(e) });
  }
}

// ---- files ----

async function open(path) {
  try {
    const f = await (await api(`/api/file?path=${encodeURIComponent(path)}`)).json();
    Object.assign(lobe, { path, hash: f.hash, name: path });
    $("editor").value = f.text;
    $("file").value = path;
    status(`opened ${path}`);
    compile();
  } catch (e) {
    showError(e);
  }
}

async function save(force) {
  if (!lobe.path) { status("this formula has no file: open one from the list", true); return; }
  try {
    const r = await (await api("/api/save", { path: lobe.path, text: $("editor").value, hash: lobe.hash, force: !!force })).json();
    lobe.hash = r.hash;
    delete fileCache[lobe.path];
    status(`saved ${lobe.path}`);
  } catch (e) {
    if (e.status === 409 && confirm(`${e.error}.\n\nOverwrite it with the formula on this page?`)) return save(true);
    showError(e);
  }
}

async function init() {
  const s = await (await api("/api/session")).json();
  $("scene").textContent = `scene: ${s.scene}`;
  const fill = (sel, names) => { for (const n of names) sel.add(new Option(n, n)); };
  fill($("file"), s.files);
  fill($("reference"), BUILTIN_REFS.map(([n]) => n).concat(s.files));
  fill($("other"), s.files);
  const phong = s.files.find((f) => f.endsWith("/phong.brdf"));
  if (phong) $("other").value = phong;
  const ed = $("editor");
  ed.addEventListener("input", () => { showDiagnostics([]); compile(); });
  ed.addEventListener("scroll", syncScroll);
  $("file").addEventListener("change", () => open($("file").value));
  $("save").addEventListener("click", () => save(false));
  for (const id of ["size"]) $(id).addEventListener("change", () => { $("frame").style.width = $("frame").style.height = `${$("size").value}px`; changed(); });
  for (const id of ["compare-on", "other", "polar"]) $(id).addEventListener("change", () => { comparePanel(); plotPanel(); });
  $("reference").addEventListener("change", analyze);
  const first = s.open || s.files.find((f) => f.endsWith("modified_schlick_vr.brdf")) || s.files[0];
  if (first) open(first);
  else { ed.value = DEFAULT_TEXT; compile(); }
}

init().catch(showError);
