// radarcal live console: server-sent events in, canvas minimap + tables out. No external code (the station is offline).
"use strict";
const $ = (id) => document.getElementById(id);
const stats = { updates: 0, log: [], positions: {}, table: [], firstRecv: null, lastRecv: null };
window.__console = stats;
const trails = {};      // label -> [[t, x, y], ...] (2 s)
const lastSeen = {};    // label -> result time of the last measurement
let field = null, lastMsg = null;
const TRAIL_S = 2.0;

// --- token & actions (token + session + increasing sequence; the server refuses anything else) ---------------------
function tokenFromHash() {
  const m = /token=([^&]+)/.exec(location.hash || "");
  if (m) { sessionStorage.setItem("radarcal-token", decodeURIComponent(m[1])); history.replaceState(null, "", location.pathname); }
  return sessionStorage.getItem("radarcal-token") || "";
}
let token = tokenFromHash(), session = null, seq = 0;
$("token").value = token;
$("token").addEventListener("change", () => { token = $("token").value.trim(); sessionStorage.setItem("radarcal-token", token); session = null; });
let holdES = null;
function hold() { if (holdES) holdES.close(); holdES = new EventSource("api/hold?session=" + encodeURIComponent(session) + (token ? "&token=" + encodeURIComponent(token) : "")); }
async function action(name, args) {
  if (!token) throw new Error("no token: paste the token printed on the terminal");
  if (!session) {
    const r = await fetch("api/claim", { method: "POST", headers: { "X-Radarcal-Token": token, "Content-Type": "application/json" }, body: "{}" });
    const j = await r.json();
    if (!r.ok) throw new Error(j.error || r.statusText);
    session = j.session; seq = 0; hold();
  }
  const r = await fetch("api/action/" + name, { method: "POST", headers: { "X-Radarcal-Token": token, "Content-Type": "application/json" },
    body: JSON.stringify({ session: session, seq: ++seq, args: args || {} }) });
  const j = await r.json();
  if (!r.ok) { if (r.status === 409) session = null; throw new Error(j.error || r.statusText); }
  return j;
}
$("dvbtn").addEventListener("click", async () => {
  try { const j = await action("double_vulnerability", {}); $("actionmsg").textContent = "trigger sent: " + JSON.stringify(j); }
  catch (e) { $("actionmsg").textContent = "refused: " + e.message; }
});

// --- minimap ---------------------------------------------------------------------------------------------------------
const cv = $("minimap"), ctx = cv.getContext("2d");
function geom() {
  const L = field ? field.size[0] : 28, W = field ? field.size[1] : 15, m = 20;
  const s = Math.min((cv.width - 2 * m) / L, (cv.height - 2 * m) / W);
  return { s: s, px: (x, y) => [m + x * s, cv.height - m - y * s] };
}
function poly(g, pts, fill, stroke) {
  ctx.beginPath();
  pts.forEach((p, i) => { const q = g.px(p[0], p[1]); if (i) ctx.lineTo(q[0], q[1]); else ctx.moveTo(q[0], q[1]); });
  ctx.closePath();
  if (fill) { ctx.fillStyle = fill; ctx.fill(); }
  if (stroke) { ctx.strokeStyle = stroke; ctx.stroke(); }
}
function drawMinimap(res) {
  const g = geom();
  ctx.clearRect(0, 0, cv.width, cv.height);
  if (field) {
    ctx.lineWidth = 2; poly(g, field.outline, "#466e46", "#fff"); ctx.lineWidth = 1;
    for (const a of field.areas) { const v = Math.max(0, Math.min(255, 110 + 120 * a.z)) | 0; poly(g, a.polygon, `rgb(${v - 30},${v},${v - 30})`, null); }
    for (const [n, p] of Object.entries(field.landmarks)) {
      if (!/_(base|outpost)$/.test(n)) continue;
      const q = g.px(p[0], p[1]); ctx.fillStyle = n.startsWith("red") ? "#e63c3c" : "#2878e6"; ctx.fillRect(q[0] - 6, q[1] - 6, 12, 12);
    }
  }
  for (const [label, tr] of Object.entries(trails)) {
    if (tr.length < 2) continue;
    ctx.strokeStyle = label.startsWith("red") ? "#ff5050" : "#3ca0ff"; ctx.beginPath();
    tr.forEach((p, i) => { const q = g.px(p[1], p[2]); if (i) ctx.lineTo(q[0], q[1]); else ctx.moveTo(q[0], q[1]); });
    ctx.stroke();
  }
  for (const k of ["lidar_tracks", "unlabelled", "clusters"]) {   // unlabelled LiDAR tracks, when the loop offers them
    for (const c of (res[k] || [])) {
      const x = c.x !== undefined ? c.x : (c.p_field || c.xy || [])[0], y = c.y !== undefined ? c.y : (c.p_field || c.xy || [])[1];
      if (x === undefined) continue;
      const q = g.px(x, y); ctx.strokeStyle = "#ddd"; ctx.beginPath(); ctx.arc(q[0], q[1], 6, 0, 2 * Math.PI); ctx.stroke();
    }
  }
  ctx.font = "12px sans-serif";
  for (const r of res.robots) {
    const q = g.px(r.x, r.y);
    ctx.fillStyle = ctx.strokeStyle = r.label.startsWith("red") ? "#ff2828" : "#1e8cff";
    ctx.beginPath(); ctx.arc(q[0], q[1], 8, 0, 2 * Math.PI);
    if (r.source === "predicted") { ctx.lineWidth = 2; ctx.stroke(); ctx.lineWidth = 1; } else ctx.fill();
    ctx.fillStyle = "#fff"; ctx.fillText(r.label.split("_").pop(), q[0] + 9, q[1] - 6);
    stats.positions[r.label] = { x: r.x, y: r.y, px: q, frame: res.frame };
  }
  const mp = res.mark_progress || (lastMsg && lastMsg.health && lastMsg.health.serial && lastMsg.health.serial.mark_progress);
  ctx.fillStyle = "#fff"; ctx.fillText(`t=${res.t.toFixed(2)} s  ${res.frame}` + (mp ? `   mark progress ${JSON.stringify(mp)}` : ""), 8, 14);
}

// --- tables ------------------------------------------------------------------------------------------------------------
const fmt = (v, d) => (v === null || v === undefined ? "-" : Number(v).toFixed(d));
function drawTable(res) {
  const rows = res.robots.map((r) => {
    if (r.source !== "predicted") lastSeen[r.label] = res.t;
    const age = lastSeen[r.label] === undefined ? null : res.t - lastSeen[r.label];
    return `<tr class="${r.label.split("_")[0]} ${r.source}" data-label="${r.label}"><td>${r.label}</td><td>${fmt(r.x, 2)}</td><td>${fmt(r.y, 2)}</td>` +
      `<td>${r.source}</td><td>${fmt(r.sigma, 3)}</td><td>${fmt(r.depth, 2)}</td><td>${fmt(r.score, 2)}</td><td>${fmt(age, 2)}</td></tr>`;
  });
  document.querySelector("#robots tbody").innerHTML = rows.join("");
  stats.table = { frame: res.frame, rows: res.robots.map((r) => ({ label: r.label, x: r.x, y: r.y, source: r.source, sigma: r.sigma })) };
}
function kv(obj) {
  if (!obj || typeof obj !== "object") return String(obj);
  return Object.entries(obj).map(([k, v]) => `<div><b>${k}</b> ${typeof v === "object" && v !== null ? kvInline(v) : String(v)}</div>`).join("");
}
function kvInline(o) {
  return Object.entries(o).map(([k, v]) => {
    const bad = (k === "connected" || k === "ok") && v === false;
    return `<span class="${bad ? "bad" : ""}">${k}=${typeof v === "object" && v !== null ? JSON.stringify(v) : v}</span>`;
  }).join(" ");
}

// --- the stream ----------------------------------------------------------------------------------------------------------
function onMessage(ev) {
  const msg = JSON.parse(ev.data), res = msg.result;
  lastMsg = msg;
  for (const r of res.robots) { (trails[r.label] = trails[r.label] || []).push([res.t, r.x, r.y]); }
  for (const [k, tr] of Object.entries(trails)) { while (tr.length && res.t - tr[0][0] > TRAIL_S) tr.shift(); if (!tr.length) delete trails[k]; }
  drawMinimap(res);
  drawTable(res);
  $("frame").textContent = res.frame; $("t").textContent = res.t.toFixed(2); $("fps").textContent = msg.fps.toFixed(1);
  $("hero").textContent = fmt(res.hero_range_m, 2);
  if (msg.info && msg.info.hero_range_offset_m !== undefined) $("heroofs").textContent = `(offset ${Number(msg.info.hero_range_offset_m).toFixed(2)} m included)`;
  const s = res.sentry;
  $("sentry").textContent = s ? (s.target ? `${s.target} dx ${fmt(s.dx, 2)} dy ${fmt(s.dy, 2)} (${fmt(s.distance, 2)} m)` : "no enemy") : "-";
  const dv = res.double_vulnerability || (msg.health && msg.health.double_vulnerability);
  $("dv").textContent = dv ? JSON.stringify(dv) : (msg.requests && msg.requests.length ? `requested ${msg.requests.length}x` : "-");
  $("health").innerHTML = Object.keys(msg.health || {}).length ? kv(msg.health) : "no health providers";
  $("timings").innerHTML = kvInline(res.latency_ms || {});
  const now = Date.now();
  const lat = now - msg.wall * 1000;
  stats.updates += 1;
  stats.firstRecv = stats.firstRecv || now; stats.lastRecv = now;
  stats.log.push({ seq: msg.seq, frame: res.frame, wall: msg.wall * 1000, shown: now, latency: lat });
  if (stats.log.length > 5000) stats.log.splice(0, 1000);
  const recent = stats.log.filter((e) => now - e.shown < 2000);
  $("rate").textContent = (recent.length / 2).toFixed(1); $("lat").textContent = lat.toFixed(0);
}
function connect() {
  const q = new URLSearchParams();
  if (token) q.set("token", token);
  if (session) q.set("session", session);
  const es = new EventSource("api/events?" + q.toString());
  es.onopen = () => { $("conn").textContent = "live"; $("conn").className = "ok"; };
  es.onerror = () => { $("conn").textContent = "disconnected (retrying)"; $("conn").className = "bad"; };
  es.onmessage = onMessage;
}
const tokq = token ? "?token=" + encodeURIComponent(token) : "";
fetch("api/field" + tokq).then((r) => r.json()).then((f) => { field = f; if (lastMsg) drawMinimap(lastMsg.result); });
setInterval(() => { $("camera").src = "api/camera.jpg?" + (token ? "token=" + encodeURIComponent(token) + "&" : "") + "n=" + Date.now(); }, 300);
connect();
