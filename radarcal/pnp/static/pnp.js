// radarcal field-pnp clicking page. Image coordinates: pixel centres at integers (pixel i spans [i-0.5, i+0.5]).
"use strict";
const $ = (id) => document.getElementById(id);
const cv = $("cv"), ctx = cv.getContext("2d");
const img = new Image();
const S = { setup: null, picks: {}, skipped: {}, history: [], current: null, nudge: [0, 0, 0, 0, 0, 0], param: 0, step: "medium",
            view: { s: 1, ox: 0, oy: 0 }, mouse: [0, 0], preview: null, updates: 0, saved: null };
window.__pnp = S;

// --- token & actions ------------------------------------------------------------------------------------------------
const m = /token=([^&]+)/.exec(location.hash || "");
if (m) { sessionStorage.setItem("radarcal-token", decodeURIComponent(m[1])); history.replaceState(null, "", location.pathname); }
const token = sessionStorage.getItem("radarcal-token") || "";
let session = null, seq = 0, busy = false, again = false;
let holdES = null;
function hold() { if (holdES) holdES.close(); holdES = new EventSource("api/hold?session=" + encodeURIComponent(session) + (token ? "&token=" + encodeURIComponent(token) : "")); }
async function post(name, args) {
  if (!session) {
    const r = await fetch("api/claim", { method: "POST", headers: { "X-Radarcal-Token": token }, body: "{}" });
    const j = await r.json();
    if (!r.ok) throw new Error(j.error || r.statusText);
    session = j.session; hold();
  }
  const r = await fetch("api/action/" + name, { method: "POST", headers: { "X-Radarcal-Token": token, "Content-Type": "application/json" },
    body: JSON.stringify({ session: session, seq: ++seq, args: args }) });
  const j = await r.json();
  if (!r.ok) throw new Error(j.error || r.statusText);
  return j;
}
const args = () => ({ picks: S.picks, nudge: S.nudge });
async function update() {          // one request in flight; the newest state is sent after it (never reordered)
  if (busy) { again = true; return; }
  busy = S.busy = true;
  try { S.preview = await post("update", args()); S.updates += 1; $("msg").textContent = ""; }
  catch (e) { $("msg").innerHTML = `<span class="bad">${e.message}</span>`; }
  busy = S.busy = false;
  render();
  if (again) { again = false; update(); }
}
async function save() {
  $("msg").textContent = "checking…";
  while (busy) await new Promise((r) => setTimeout(r, 20));
  busy = S.busy = true;
  try {
    const j = await post("save", args());
    S.saved = j;
    $("msg").innerHTML = j.ok ? `<span class="ok">saved: ${j.summary.message || ""}</span> — the command writes the bundle and exits; close this page.`
                              : `<span class="bad">not saved: ${j.error}</span>`;
  } catch (e) { $("msg").innerHTML = `<span class="bad">${e.message}</span>`; }
  busy = S.busy = false;
}

// --- view ----------------------------------------------------------------------------------------------------------------
const toScreen = (u, v) => [(u + 0.5) * S.view.s + S.view.ox, (v + 0.5) * S.view.s + S.view.oy];
const toImage = (x, y) => [(x - S.view.ox) / S.view.s - 0.5, (y - S.view.oy) / S.view.s - 0.5];
S.toScreen = toScreen; S.toImage = toImage;
function fit() {
  const W = cv.width, H = cv.height, w = img.naturalWidth || 1, h = img.naturalHeight || 1;
  const s = Math.min(W / w, H / h);
  S.view = { s: s, ox: Math.round((W - w * s) / 2), oy: Math.round((H - h * s) / 2) };
}
function zoomAt(x, y, f) {
  const [u, v] = toImage(x, y);
  S.view.s = Math.max(0.05, Math.min(64, S.view.s * f));
  S.view.ox = x - (u + 0.5) * S.view.s; S.view.oy = y - (v + 0.5) * S.view.s;
  render();
}
function resize() { cv.width = $("view").clientWidth; cv.height = $("view").clientHeight; fit(); render(); }

// --- landmarks -------------------------------------------------------------------------------------------------------------
function nextLandmark() {
  if (S.current && !S.picks[S.current]) return S.current;
  return S.setup.order.find((n) => !S.picks[n] && !S.skipped[n]) || null;
}
function pick(name, u, v) {
  S.history.push([name, S.picks[name] || null]);
  S.picks[name] = [u, v];
  if (S.current === name) S.current = null;
  update(); render();
}
function listItems() {
  const cur = nextLandmark(), p = S.preview, res = (p && p.residuals) || {};
  const item = (n, i) => {
    const st = S.picks[n] ? "picked" : S.skipped[n] ? "skipped" : n === cur ? "current" : "";
    const r = res[n] ? Math.hypot(res[n][0], res[n][1]).toFixed(2) + " px" : "";
    return `<li class="${st}" data-name="${n}">${n}<span class="res">${r}</span></li>`;
  };
  $("order").innerHTML = S.setup.order.map(item).join("");
  $("extras").innerHTML = S.setup.extras.map(item).join("");
  for (const li of document.querySelectorAll("li[data-name]")) li.onclick = () => { S.current = li.dataset.name; delete S.skipped[S.current]; render(); };
}
function poseTable() {
  const p = S.preview, names = S.setup.params, st = S.setup.steps[S.step];
  $("pose").innerHTML = names.map((n, i) => {
    const v = p && p.pose ? (i < 3 ? p.pose[i].toFixed(3) + " m" : p.view_deg[i - 3].toFixed(2) + "°") : "-";
    const d = S.nudge[i] ? ` <span class="dim">nudge ${S.nudge[i] > 0 ? "+" : ""}${S.nudge[i].toFixed(i < 3 ? 2 : 1)}${i < 3 ? " m" : "°"}</span>` : "";
    return `<tr><td class="${i === S.param ? "sel" : ""}">${i + 1} ${n}</td><td>${v}${d}</td></tr>`;
  }).join("");
  $("step").textContent = S.step; $("stepval").textContent = `(${st[0]} m, ${st[1]}°)`;
  let s = "no pose yet: click at least four landmarks";
  if (p && p.pose) s = (p.base === "picks" ? "solved from the picks" : "the bundle's stored pose") + (p.rms_px !== null ? `, RMS ${p.rms_px.toFixed(2)} px` : "") +
    " (yaw: heading of the optical axis from field +x, pitch: its tilt, + up; roll: of the image about it)";
  if (p && p.error) s = `<span class="bad">${p.error}</span>` + (p.pose ? "<br>" + s : "");
  $("status").innerHTML = s;
}

// --- drawing ----------------------------------------------------------------------------------------------------------
function render() {
  if (!S.setup) return;
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.clearRect(0, 0, cv.width, cv.height);
  ctx.imageSmoothingEnabled = S.view.s < 2;
  ctx.setTransform(S.view.s, 0, 0, S.view.s, S.view.ox, S.view.oy);
  if (img.complete) ctx.drawImage(img, 0, 0);
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  const p = S.preview;
  if (p && p.overlay) {
    ctx.lineWidth = 1.5;
    for (const l of p.overlay.lines) {
      ctx.strokeStyle = l.kind === "outline" ? "#ffffff" : "#ffd000";
      ctx.beginPath();
      l.uv.forEach((q, i) => { const s = toScreen(q[0], q[1]); if (i) ctx.lineTo(s[0], s[1]); else ctx.moveTo(s[0], s[1]); });
      ctx.stroke();
    }
    ctx.font = "11px sans-serif";
    for (const [n, q] of Object.entries(p.overlay.landmarks)) {
      if (!q) continue;
      const s = toScreen(q[0], q[1]);
      ctx.strokeStyle = ctx.fillStyle = "#ff4040";
      ctx.beginPath(); ctx.moveTo(s[0] - 6, s[1]); ctx.lineTo(s[0] + 6, s[1]); ctx.moveTo(s[0], s[1] - 6); ctx.lineTo(s[0], s[1] + 6); ctx.stroke();
      ctx.fillText(n, s[0] + 6, s[1] - 5);
    }
  }
  ctx.font = "bold 12px sans-serif";
  for (const [n, q] of Object.entries(S.picks)) {
    const s = toScreen(q[0], q[1]);
    ctx.strokeStyle = "#40ff60"; ctx.lineWidth = 2;
    ctx.beginPath(); ctx.arc(s[0], s[1], 7, 0, 2 * Math.PI); ctx.stroke();
    ctx.beginPath(); ctx.moveTo(s[0] - 2, s[1]); ctx.lineTo(s[0] + 2, s[1]); ctx.moveTo(s[0], s[1] - 2); ctx.lineTo(s[0], s[1] + 2); ctx.stroke();
    const r = p && p.residuals && p.residuals[n];
    if (r) { ctx.strokeStyle = "#ff40ff"; ctx.beginPath(); ctx.moveTo(s[0], s[1]); ctx.lineTo(s[0] - r[0] * S.view.s, s[1] - r[1] * S.view.s); ctx.stroke(); }
    ctx.fillStyle = "#40ff60"; ctx.fillText(n, s[0] + 9, s[1] + 14);
  }
  const cur = nextLandmark();
  ctx.fillStyle = "rgba(0,0,0,0.6)"; ctx.fillRect(0, 0, cv.width, 24);
  ctx.fillStyle = "#ffd84a"; ctx.font = "bold 14px sans-serif";
  ctx.fillText(cur ? `click ${cur}  (${Object.keys(S.picks).length} picked)` : `all picked (${Object.keys(S.picks).length}) — check the outline, nudge if needed, save`, 8, 17);
  listItems(); poseTable();
}

// --- input ------------------------------------------------------------------------------------------------------------
let drag = null;
function pickUnder(x, y) {
  let best = null, bd = 9;
  for (const [n, q] of Object.entries(S.picks)) { const s = toScreen(q[0], q[1]); const d = Math.hypot(s[0] - x, s[1] - y); if (d < bd) { bd = d; best = n; } }
  return best;
}
const pos = (e) => { const r = cv.getBoundingClientRect(); return [e.clientX - r.left, e.clientY - r.top]; };
cv.addEventListener("contextmenu", (e) => e.preventDefault());
cv.addEventListener("mousedown", (e) => {
  const [x, y] = pos(e);
  if (e.button === 2 || e.button === 1 || e.shiftKey) { drag = { pan: true, x: x, y: y, ox: S.view.ox, oy: S.view.oy }; return; }
  const n = pickUnder(x, y);
  drag = n ? { name: n, moved: false, start: S.picks[n].slice() } : { click: true, x: x, y: y };
});
cv.addEventListener("mousemove", (e) => {
  const [x, y] = pos(e);
  S.mouse = [x, y];
  if (!drag) return;
  if (drag.pan) { S.view.ox = drag.ox + x - drag.x; S.view.oy = drag.oy + y - drag.y; render(); }
  else if (drag.name) { drag.moved = true; S.picks[drag.name] = toImage(x, y); render(); }
});
window.addEventListener("mouseup", (e) => {
  if (!drag) return;
  const [x, y] = pos(e);
  if (drag.name && drag.moved) { S.picks[drag.name] = toImage(x, y); S.history.push([drag.name, drag.start]); update(); }
  else if (drag.click && Math.hypot(x - drag.x, y - drag.y) < 4) {
    const n = nextLandmark();
    if (n) { const [u, v] = toImage(x, y); pick(n, u, v); }
  }
  drag = null; render();
});
cv.addEventListener("wheel", (e) => { e.preventDefault(); const [x, y] = pos(e); zoomAt(x, y, e.deltaY < 0 ? 1.25 : 0.8); }, { passive: false });
window.addEventListener("keydown", (e) => {
  const k = e.key;
  const [x, y] = S.mouse;
  if (k === "z") zoomAt(x, y, 2);
  else if (k === "Z") zoomAt(x, y, 0.5);
  else if (k === "v") { fit(); render(); }
  else if (k === "s") { const n = nextLandmark(); if (n) { S.skipped[n] = true; S.current = null; render(); } }
  else if (k === "u") { const h = S.history.pop(); if (h) { if (h[1]) S.picks[h[0]] = h[1]; else delete S.picks[h[0]]; update(); render(); } }
  else if (k === "Delete" || k === "Backspace") { const n = pickUnder(x, y); if (n) { S.history.push([n, S.picks[n]]); delete S.picks[n]; update(); render(); } }
  else if (k >= "1" && k <= "6") { S.param = Number(k) - 1; render(); }
  else if (k === "c" || k === "m" || k === "f") { S.step = { c: "coarse", m: "medium", f: "fine" }[k]; render(); }
  else if (k === "ArrowLeft" || k === "ArrowRight" || k === "-" || k === "+" || k === "=") {
    const sgn = (k === "ArrowRight" || k === "+" || k === "=") ? 1 : -1;
    const st = S.setup.steps[S.step][S.param < 3 ? 0 : 1];
    S.nudge[S.param] = Math.round((S.nudge[S.param] + sgn * st) * 1e6) / 1e6;
    update(); render();
  }
  else if (k === "0") { S.nudge = [0, 0, 0, 0, 0, 0]; update(); render(); }
  else if (k === "Enter") save();
  else return;
  e.preventDefault();
});
$("save").addEventListener("click", save);

// --- start -------------------------------------------------------------------------------------------------------------
const tokq = token ? "?token=" + encodeURIComponent(token) : "";
fetch("api/setup" + tokq).then((r) => r.json()).then((setup) => {
  S.setup = setup;
  Object.assign(S.picks, setup.initial || {});
  img.onload = () => { resize(); update(); S.ready = true; };
  img.src = "image.png" + tokq;
});
window.addEventListener("resize", resize);
