// The pilot console's page: camera with HUD, map, learning plot, session controls and the
// gamepad (Gamepad API, standard layout) or keyboard sent to the companion over one WebSocket.
"use strict";

const SEND_HZ = 30;            // at least this often (>= the control rate, 10.5 Hz) ...
const POLL_MS = 8;             // ... and at once when the sticks change (polled this often)
const KEY_STICK = 0.6;         // stick deflection of a held key
const COLOURS = { person: "#ff9800", policy: "#29b6f6", hold: "#e53935" };

const C = window.colConsole = {
  framesDrawn: 0, frameLatenciesMs: [], drawTimesMs: [], frameStamps: [], steps: [], records: [], status: null,
  hello: null, lastStep: null, track: [], inputsSent: 0, connected: false, notices: [],
};
let ws = null, seq = 0, pendingBitmap = null, lastFrame = null, truth = null;
const keys = new Set();

// ----- socket ------------------------------------------------------------------------------
function connect() {
  ws = new WebSocket(`ws://${location.host}/ws${location.search}`);  // ?token=... when the console asks for one
  ws.binaryType = "arraybuffer";
  ws.onopen = () => { C.connected = true; setLink(true); };
  ws.onclose = () => {
    C.connected = false; setLink(false);
    showBanner("Link to the companion lost. If you were flying, the vehicle holds position. Reconnecting...");
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => (typeof ev.data === "string" ? onJson(JSON.parse(ev.data)) : onFrame(ev.data));
}

function send(obj) { if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(obj)); }
function command(name, extra) { send(Object.assign({ type: "command", name }, extra || {})); }

function onJson(m) {
  if (m.type === "hello") {
    C.hello = m; C.track = m.track.map(([n, e, who]) => ({ n, e, who }));
    C.trackEpisode = m.track_episode;
    C.records = m.records; onStatus(m.status); drawPlot(); fillTable(); hideBanner();
    document.getElementById("episodes").value = m.episodes_default;
  } else if (m.type === "status") { onStatus(m); }
  else if (m.type === "step") { onStep(m); }
  else if (m.type === "episode") { C.records.push(m); drawPlot(); fillTable(); drawMap(); }
  else if (m.type === "notice") { C.notices.push(m.text); setText("run-state", m.text); }
  else if (m.type === "error") { showBanner(m.message, true); }
}

function onStatus(s) {
  C.status = s; if (s.truth) truth = s.truth;
  const r = s.run;
  let text = `${r.state}` + (r.condition ? ` - ${r.condition}, ${r.episodes} episodes` : "") +
    (r.episode !== null && r.episode !== undefined ? ` - episode ${r.episode} (${r.phase})` : "") +
    (r.paused ? " - paused after this episode" : "") + (r.error ? ` - ${r.error}` : "");
  setText("run-state", text);
  document.getElementById("pause").textContent = r.paused ? "Resume" : "Pause";
  const running = ["starting", "running", "paused", "stopping"].includes(r.state);
  document.getElementById("start").disabled = running;
  if (running && r.condition) {  // the form shows the run that is going
    document.getElementById("condition").value = r.condition;
    document.getElementById("episodes").value = r.episodes;
  }
  if (s.input.hold_reason) {
    showBanner(`HOLDING POSITION: ${s.input.hold_reason}. Hold the trigger to fly, or "Hand back to policy".`);
  } else if (C.connected) { hideBanner(); }
  drawMap();
}

function onStep(m) {
  if (C.trackEpisode !== m.episode) { C.track = []; C.trackEpisode = m.episode; }
  C.lastStep = m;
  C.steps.push({ episode: m.episode, step: m.step, who: m.who, recorded: m.recorded, tag: m.tag,
    wallMs: m.wall_ms, forward: m.setpoint.forward_m_s });
  if (C.steps.length > 20000) C.steps.splice(0, 10000);
  C.track.push({ n: m.position_ne_m[0], e: m.position_ne_m[1], who: m.who });
  if (m.who === "hold" && !(C.status && C.status.input.hold_reason)) {
    showBanner("HOLDING POSITION: the person's input is lost. The policy does not take over.");
  }
  drawMap();
  if (!lastFrame) drawVideo();
}

// ----- camera and HUD ----------------------------------------------------------------------
function onFrame(buf) {
  const dv = new DataView(buf);
  const header = { number: dv.getUint32(0, true), stampMs: dv.getUint32(4, true), sentMs: dv.getFloat64(8, true) };
  createImageBitmap(new Blob([buf.slice(16)], { type: "image/jpeg" })).then((bmp) => {
    if (lastFrame && lastFrame.bitmap) lastFrame.bitmap.close();
    lastFrame = { bitmap: bmp, header };
    drawVideo();
    const now = performance.timeOrigin + performance.now();
    C.framesDrawn += 1;
    C.drawTimesMs.push(now); C.frameLatenciesMs.push(now - header.sentMs);
    C.frameStamps.push([header.stampMs, header.sentMs, now]);
    if (C.drawTimesMs.length > 4000) {
      C.drawTimesMs.splice(0, 2000); C.frameLatenciesMs.splice(0, 2000); C.frameStamps.splice(0, 2000);
    }
  });
}

function drawVideo() {
  const cv = document.getElementById("video"), g = cv.getContext("2d");
  g.fillStyle = "#000"; g.fillRect(0, 0, cv.width, cv.height);
  if (lastFrame) g.drawImage(lastFrame.bitmap, 0, 0, cv.width, cv.height);
  else { g.fillStyle = "#888"; g.font = "16px sans-serif"; g.fillText("no camera frames yet", 240, 240); }
  drawHud(g, cv.width, cv.height);
}

function drawHud(g, w, h) {
  const s = C.lastStep, st = C.status;
  g.font = "bold 15px monospace"; g.textBaseline = "top";
  const line = (text, x, y, colour) => {
    g.fillStyle = "rgba(0,0,0,0.55)"; g.fillRect(x - 3, y - 2, g.measureText(text).width + 6, 19);
    g.fillStyle = colour || "#fff"; g.fillText(text, x, y);
  };
  if (!s) { line("waiting for the first control step", 10, 10); return; }
  if (s.pad) {
    const k = w / s.image_size_px[0];
    g.strokeStyle = s.pad.partial ? "#ffeb3b" : "#00e676"; g.lineWidth = 2;
    g.beginPath(); g.arc(s.pad.u * k, s.pad.v * k, s.pad.r * k, 0, 2 * Math.PI); g.stroke();
    g.beginPath(); g.moveTo(s.pad.u * k - 8, s.pad.v * k); g.lineTo(s.pad.u * k + 8, s.pad.v * k);
    g.moveTo(s.pad.u * k, s.pad.v * k - 8); g.lineTo(s.pad.u * k, s.pad.v * k + 8); g.stroke();
  }
  line(`ALT ${s.altitude_m.toFixed(2)} m`, 10, 10);
  line(`VS  ${(s.climb_m_s >= 0 ? "+" : "") + s.climb_m_s.toFixed(2)} m/s`, 10, 32);
  line(s.pad ? "PAD seen" : "PAD not visible", 10, 54, s.pad ? "#00e676" : "#ffeb3b");
  const who = { person: "PERSON FLIES", policy: "POLICY FLIES", hold: "HOLDING (input lost)" }[s.who];
  g.font = "bold 20px sans-serif";
  line(who, w - g.measureText(who).width - 14, 10, COLOURS[s.who]);
  g.font = "bold 15px monospace";
  const loss = s.loss === null ? "-" : s.loss.toExponential(2);
  line(`episode ${s.episode}  ${s.phase}  step ${s.step}`, 10, h - 66);
  line(`policy v${s.policy_version === null ? "-" : s.policy_version}  loss ${loss}`, 10, h - 44);
  line(`human samples ${s.samples}` + (st ? `  frames ${C.framesDrawn}` : ""), 10, h - 22);
}

// ----- map and plot ------------------------------------------------------------------------
function padNe() {
  if (truth && truth.pad_ned) return [truth.pad_ned[0], truth.pad_ned[1]];
  return C.hello ? [C.hello.pad_ned_m[0], C.hello.pad_ned_m[1]] : [0, 0];
}

function drawMap() {
  const cv = document.getElementById("map"), g = cv.getContext("2d"), W = cv.width;
  const [pn, pe] = padNe();
  let span = 6;
  for (const p of C.track) span = Math.max(span, Math.abs(p.n - pn) + 1, Math.abs(p.e - pe) + 1);
  const k = (W / 2) / span, X = (e) => W / 2 + (e - pe) * k, Y = (n) => W / 2 - (n - pn) * k;
  g.fillStyle = "#0f1215"; g.fillRect(0, 0, W, W);
  g.strokeStyle = "#2a3038"; g.lineWidth = 1;
  for (let m = -Math.floor(span); m <= span; m++) {
    g.beginPath(); g.moveTo(X(pe + m), 0); g.lineTo(X(pe + m), W); g.stroke();
    g.beginPath(); g.moveTo(0, Y(pn + m)); g.lineTo(W, Y(pn + m)); g.stroke();
  }
  const r = C.hello ? C.hello.pad_radius_m : 0.5;
  g.fillStyle = "#d028d2"; g.beginPath(); g.arc(X(pe), Y(pn), r * k, 0, 2 * Math.PI); g.fill();
  for (let i = 1; i < C.track.length; i++) {
    const a = C.track[i - 1], b = C.track[i];
    g.strokeStyle = COLOURS[b.who] || "#fff"; g.lineWidth = 2;
    g.beginPath(); g.moveTo(X(a.e), Y(a.n)); g.lineTo(X(b.e), Y(b.n)); g.stroke();
  }
  for (const rec of C.records) {
    if (!rec.touchdown_ne_m) continue;
    g.fillStyle = rec.success ? "#66bb6a" : "#ef5350";
    g.beginPath(); g.arc(X(rec.touchdown_ne_m[1]), Y(rec.touchdown_ne_m[0]), 4, 0, 2 * Math.PI); g.fill();
  }
  const v = truth && truth.vehicle_ned ? truth.vehicle_ned : (C.lastStep ? [...C.lastStep.position_ne_m] : null);
  if (v) { g.strokeStyle = "#fff"; g.lineWidth = 2; g.strokeRect(X(v[1]) - 4, Y(v[0]) - 4, 8, 8); }
  g.fillStyle = "#aab"; g.font = "11px sans-serif"; g.fillText(`grid 1 m, N up`, 6, W - 8);
}

function drawPlot() {
  const cv = document.getElementById("plot"), g = cv.getContext("2d"), W = cv.width, H = cv.height;
  g.fillStyle = "#0f1215"; g.fillRect(0, 0, W, H);
  const recs = C.records, n = recs.length;
  if (!n) { g.fillStyle = "#889"; g.font = "12px sans-serif"; g.fillText("no finished episodes yet", 80, H / 2); return; }
  let wins = 0; const rate = [], samples = [];
  recs.forEach((r, i) => { wins += r.success ? 1 : 0; rate.push(wins / (i + 1)); samples.push(r.dataset_size); });
  const maxS = Math.max(1, ...samples), X = (i) => 20 + (n === 1 ? 0.5 : i / (n - 1)) * (W - 40);
  const series = (vals, top, colour) => {
    g.strokeStyle = colour; g.fillStyle = colour; g.lineWidth = 2; g.beginPath();
    vals.forEach((v, i) => { const y = H - 15 - (v / top) * (H - 30); i ? g.lineTo(X(i), y) : g.moveTo(X(i), y); });
    g.stroke();
    vals.forEach((v, i) => { g.beginPath(); g.arc(X(i), H - 15 - (v / top) * (H - 30), 3, 0, 2 * Math.PI); g.fill(); });
  };
  series(rate, 1, "#66bb6a"); series(samples, maxS, "#ffca28");
  g.fillStyle = "#aab"; g.font = "11px sans-serif";
  g.fillText(`success ${Math.round(100 * rate[n - 1])}% of ${n}`, 6, 12);
  g.fillText(`${samples[n - 1]} samples`, W - 80, 12);
}

function fillTable() {
  const body = document.querySelector("#episodes-table tbody");
  body.innerHTML = "";
  for (const r of C.records) {
    const tr = document.createElement("tr");
    const cells = [r.episode, r.phase, r.outcome, r.success === null ? "-" : (r.success ? "yes" : "no"), r.steps,
      r.human_samples, r.interventions, r.touchdown_distance_m === null ? "-" : r.touchdown_distance_m.toFixed(2),
      r.dataset_size, r.policy_version === null ? "-" : r.policy_version];
    for (const c of cells) { const td = document.createElement("td"); td.textContent = c; tr.appendChild(td); }
    body.appendChild(tr);
  }
}

// ----- input -------------------------------------------------------------------------------
function gamepad() {
  const pads = navigator.getGamepads ? navigator.getGamepads() : [];
  for (const p of pads || []) if (p && p.connected !== false) return p;
  return null;
}

function readInput() {
  const p = gamepad();
  if (p) {
    return { source: p.id || "gamepad", axes: Array.from(p.axes).slice(0, 4),
      buttons: Array.from(p.buttons).map((b) => (typeof b === "object" ? b.value : Number(b))) };
  }
  const k = (a, b) => (keys.has(a) ? -KEY_STICK : 0) + (keys.has(b) ? KEY_STICK : 0);
  const buttons = new Array(8).fill(0); buttons[7] = keys.has(" ") ? 1 : 0;
  return { source: "keyboard", axes: [k("a", "d"), k("w", "s"), k("ArrowLeft", "ArrowRight"), k("ArrowUp", "ArrowDown")], buttons };
}

let lastSent = { key: "", at: 0 };
function sendInput() {
  const inp = readInput(), now = performance.now();
  const key = JSON.stringify([inp.axes, inp.buttons[7]]);
  if (key === lastSent.key && now - lastSent.at < 1000 / SEND_HZ) return;
  lastSent = { key, at: now };
  setText("pad-state", inp.source === "keyboard" ? "no gamepad: keyboard" : `gamepad: ${inp.source}`);
  drawStick("stick-left", inp.axes[0], inp.axes[1]);
  drawStick("stick-right", inp.axes[2], inp.axes[3]);
  document.getElementById("trigger-bar").style.height = `${Math.round(100 * (inp.buttons[7] || 0))}%`;
  if (!C.connected) return;
  send({ type: "input", axes: inp.axes, buttons: inp.buttons, seq: seq++, t: performance.timeOrigin + now });
  C.inputsSent += 1;
}

function drawStick(id, x, y) {
  const cv = document.getElementById(id), g = cv.getContext("2d"), c = cv.width / 2;
  g.clearRect(0, 0, cv.width, cv.height);
  if (C.hello) { g.strokeStyle = "#333"; g.strokeRect(c - C.hello.deadband * 38, c - C.hello.deadband * 38, C.hello.deadband * 76, C.hello.deadband * 76); }
  g.fillStyle = "#9fb3c8"; g.beginPath(); g.arc(c + (x || 0) * 36, c + (y || 0) * 36, 8, 0, 2 * Math.PI); g.fill();
}

// ----- page furniture ----------------------------------------------------------------------
function setText(id, text) { document.getElementById(id).textContent = text; }
function setLink(ok) { const b = document.getElementById("link"); b.textContent = ok ? "connected" : "disconnected"; b.className = `badge ${ok ? "ok" : "bad"}`; }
function showBanner(text) { const b = document.getElementById("banner"); b.textContent = text; b.classList.remove("hidden"); }
function hideBanner() { document.getElementById("banner").classList.add("hidden"); }

window.addEventListener("keydown", (e) => {
  if (["INPUT", "SELECT"].includes(document.activeElement.tagName)) return;
  keys.add(e.key.length === 1 ? e.key.toLowerCase() : e.key);
  if (e.key.startsWith("Arrow") || e.key === " ") e.preventDefault();
});
window.addEventListener("keyup", (e) => keys.delete(e.key.length === 1 ? e.key.toLowerCase() : e.key));
window.addEventListener("blur", () => keys.clear());
document.getElementById("start").onclick = () => command("start", {
  condition: document.getElementById("condition").value, episodes: parseInt(document.getElementById("episodes").value, 10) });
document.getElementById("pause").onclick = () => command(C.status && C.status.run.paused ? "resume" : "pause");
document.getElementById("next").onclick = () => command("next");
document.getElementById("stop").onclick = () => command("stop");
document.getElementById("handback").onclick = () => command("hand_back");

connect();
setInterval(sendInput, POLL_MS);
drawVideo(); drawMap(); drawPlot();
