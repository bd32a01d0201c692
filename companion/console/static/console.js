// The pilot console's page: camera with HUD, map, learning plot, session controls and the
// gamepad (Gamepad API, standard layout) or keyboard sent to the companion over one WebSocket.
// One page is the pilot (it asked and was told); the others watch and send nothing.
"use strict";

const SEND_HZ = 30;            // at least this often (>= the control rate, 10.5 Hz) ...
const POLL_MS = 8;             // ... and at once when the sticks change (polled this often)
const KEY_STICK = 0.6;         // stick deflection of a held key
const STALE_MS = 1000;         // no camera frame for this long while a run flies: "video stale"
const STEP_STALE_MS = 1500;    // no control step for this long: the HUD stops saying who flies
const FRAMES_KEPT = 10;        // recent frames by number, to draw each detection on its own frame
const ACTIVE = ["starting", "running", "ready", "paused", "stopping"];
const FLYING = ["starting", "running", "stopping"];  // states whose steps fly: a vehicle-side gap matters
const AXES_NEEDED = 4, BUTTONS_NEEDED = 8;  // both sticks and button 7 (the right trigger): the server refuses less
const COLOURS = { person: "#ff9800", policy: "#29b6f6", hold: "#e53935" };

const C = window.colConsole = {
  study: null,
  framesDrawn: 0, frameLatenciesMs: [], drawTimesMs: [], frameStamps: [], steps: [], records: [], status: null,
  hello: null, lastStep: null, track: [], inputsSent: 0, connected: false, notices: [], errors: [],
  role: null, videoState: "waiting", hudState: "waiting", clockOffsetMs: 0,  // a test may move the clock
  // the page's link to the console: connecting (first time), open, lost (it dropped; reconnecting),
  // gone (a reconnect failed: the console stopped, or the network is down)
  link: "connecting", failedAttempts: 0, lostAt: null, gap: null, banner: "",
  now: () => performance.now() + C.clockOffsetMs,
};
let ws = null, seq = 0, lastFrame = null, truth = null, lastFrameAt = null, lastStepAt = null;
const frames = new Map();  // frame number -> ImageBitmap
const keys = new Set();

// ----- socket ------------------------------------------------------------------------------
// This tab's key, kept across reloads of the tab: a pilot whose link drops gets the role back
// when the same tab reconnects soon enough (companion/console/roles.py).
const TAB = (() => {
  let key = null;
  try { key = sessionStorage.getItem("col-tab"); } catch (e) { /* storage off: a key per load */ }
  if (!/^[0-9a-f]{32}$/.test(key || "")) {
    key = Array.from(crypto.getRandomValues(new Uint8Array(16)), (b) => b.toString(16).padStart(2, "0")).join("");
    try { sessionStorage.setItem("col-tab", key); } catch (e) { /* ignored */ }
  }
  return key;
})();

function socketUrl() {
  const query = new URLSearchParams(location.search);  // ?token=... when the console asks for one
  query.set("tab", TAB);
  return `ws://${location.host}/ws?${query}`;
}

function connect() {
  const sock = ws = new WebSocket(socketUrl());
  let opened = false;
  sock.binaryType = "arraybuffer";
  sock.onopen = () => {
    opened = true; C.connected = true; C.link = "open"; C.failedAttempts = 0; C.lostAt = null; setLink();
  };
  sock.onclose = () => {
    if (ws !== sock) return;
    if (C.lostAt === null) C.lostAt = new Date();
    if (opened) C.link = "lost";  // it was up: a moment's drop, or the console stopped
    else { C.failedAttempts += 1; C.link = "gone"; }  // no answer at all: say so, and keep trying
    C.connected = false; C.role = null;
    offline();
    setTimeout(connect, 1000);
  };
  sock.onmessage = (ev) => (typeof ev.data === "string" ? onJson(JSON.parse(ev.data)) : onFrame(ev.data));
}

// The page without its console: it says so, its controls are off and greyed, and nothing on it
// pretends to know the run's state or this page's role (the last known state is named as such).
function offline() {
  setLink();
  const b = document.getElementById("role");
  b.textContent = "no role: not connected"; b.className = "badge";
  document.getElementById("take-role").textContent = "Fly from this page";
  const last = C.status ? C.status.run.state : null;
  setText("run-state", `not connected: the run's state is unknown` + (last ? ` (last known: ${last})` : ""));
  refreshBanner(); updateControls(); drawVideo();
}

function goneText() {
  const since = C.lostAt ? C.lostAt.toLocaleTimeString() : "the start";
  return `NO CONSOLE: this page cannot reach the console at ${location.host} (${C.failedAttempts} ` +
    `failed attempt${C.failedAttempts === 1 ? "" : "s"} since ${since}): it stopped, or the network is down. Nothing ` +
    "on this page acts, and what it shows is the last it knew. If the console still runs and the person was " +
    "flying, the vehicle holds position; if it stopped, so did its run (a real vehicle's own failsafe " +
    "acts when setpoints stop). Trying again every second.";
}
const LINK_LOST_TEXT = "LINK LOST: this page's link to the console dropped. If you were flying, the vehicle " +
  "holds position. Nothing on this page acts until it is back. Reconnecting...";

function send(obj) { if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(obj)); }
function command(name, extra) { send(Object.assign({ type: "command", name }, extra || {})); }
const isPilot = () => C.connected && C.role && C.role.role === "pilot";
const runState = () => (C.status ? C.status.run.state : "idle");

function onJson(m) {
  if (m.type === "hello") {
    C.hello = m; C.track = m.track.map(([n, e, who]) => ({ n, e, who }));
    C.trackEpisode = m.track_episode; C.records = m.records; hideBanner();
    document.getElementById("episodes").value = m.episodes_default;
    onRole(m.role); onStatus(m.status); drawPlot(); fillTable();
  } else if (m.type === "status") { onStatus(m); }
  else if (m.type === "role") { onRole(m); }
  else if (m.type === "step") { onStep(m); }
  else if (m.type === "episode") { C.records.push(m); drawPlot(); fillTable(); drawMap(); updateControls(); }
  else if (m.type === "discarded") {
    for (const r of C.records) if (r.episode === m.episode) r.discarded = m.reason;
    drawPlot(); fillTable(); updateControls();
  } else if (m.type === "notice") {
    C.notices.push(m.text); setText("run-state", m.text);
    if (m.pilot_lost) showBanner(`${m.text}. Any page may now press "Fly from this page".`);
  } else if (m.type === "gap") { C.gap = m.gap || null; refreshBanner(); }
  else if (m.type === "error") { addError(m.message, m.count); }
}

function onRole(r) {
  C.role = r;
  const b = document.getElementById("role");
  if (r.role === "pilot") { b.textContent = `PILOT (page ${r.page})`; b.className = "badge pilot"; }
  else { b.textContent = r.pilot_page ? `watching: page ${r.pilot_page} flies` : "watching: no pilot"; b.className = "badge"; }
  document.getElementById("take-role").textContent = r.role === "pilot" ? "Give up the pilot role" : "Fly from this page";
  refreshBanner();
  updateControls();
}

// A watching page is always told who flies, also while the vehicle holds (it cannot act on a hold).
function watchText() {
  const r = C.role || {};
  return r.pilot_page ? `This page watches; page ${r.pilot_page} is the pilot. Its sticks and buttons are the only ones that act.`
    : `This page watches and nobody is the pilot. Press "Fly from this page" to fly.`;
}

// The one place that decides the banner from what the page knows (link, status, gap, last step,
// role): the status (4 Hz) and the steps (10 Hz) must not take turns at it, or a hold flickers
// away. It names why the session holds: the page's own link, the vehicle's side (a gap: stale
// telemetry, the vehicle link, a missing video frame), refused sticks, the pilot's role given up.
const INPUT_LOST = "the person's input is lost";
const HOLD_STEP_FRESH_MS = 3000;  // a hold step older than this (the episode ended, a new one starts) is history
function stepHolds() {
  const st = runState();
  return !!C.lastStep && C.lastStep.who === "hold" && ACTIVE.includes(st) && st !== "ready"
    && C.now() - lastStepAt < HOLD_STEP_FRESH_MS;
}

function holdReasons() {
  const s = C.status, reasons = [];
  const gap = C.gap && FLYING.includes(runState()) ? C.gap : null;
  if (gap) reasons.push({ text: `${gap.holding ? "HOLDING POSITION" : "NOT RECORDED"}: ${gap.text}`, latched: false });
  if (s && s.input.hold_reason && ACTIVE.includes(runState())) reasons.push({ text: `HOLDING POSITION: ${s.input.hold_reason}`, latched: true });
  else if (stepHolds()) {
    const why = C.lastStep.hold_reason || (s && s.input.lost_reason) || INPUT_LOST;
    reasons.push({ text: `HOLDING POSITION: ${why}; the policy does not take over`, latched: false });
  }
  return reasons;
}

function refreshBanner() {
  document.body.classList.toggle("offline", C.link === "lost" || C.link === "gone");
  if (C.link === "gone") { showBanner(goneText(), "gone"); return; }
  if (C.link === "lost") { showBanner(LINK_LOST_TEXT); return; }
  if (!C.connected) return;  // connecting for the first time
  const reasons = holdReasons();
  if (reasons.length) {
    const text = reasons.map((r) => r.text).join(". ") + ".";
    if (!isPilot()) showBanner(`${text} ${watchText()}`, "watch");
    else if (reasons.some((r) => r.latched)) showBanner(`${text} Hold the trigger to fly, or "Hand back to policy".`);
    else showBanner(text);
  } else if (isPilot()) hideBanner();
  else if (C.role) showBanner(watchText(), "watch");
}

function onStatus(s) {
  C.status = s;
  if ("truth" in s) truth = s.truth || null;  // the session's own status (a state change) carries none
  if ("gap" in s.run) C.gap = s.run.gap || null;
  const r = s.run;
  let text = `${r.state}` + (r.condition ? ` - ${r.condition}, ${r.episodes} episodes` : "") +
    (r.episode !== null && r.episode !== undefined ? ` - episode ${r.episode} (${r.phase})` : "") +
    (r.state === "ready" ? ` - episode ${r.ready_for} (${r.phase}) waits: press Go when ready` : "") +
    (r.paused ? " - paused after this episode" : "") + (r.error ? ` - ${r.error}` : "");
  if (r.stage && r.state !== "ready") text += ` - ${r.stage}, ${Math.round(r.since_start_s || 0)} s since Start`;
  if (!ACTIVE.includes(r.state) && r.summary) text = r.summary;
  setText("run-state", text);
  document.getElementById("pause").textContent = r.paused ? "Resume" : "Pause";
  document.getElementById("auto").checked = !!r.auto;
  if (ACTIVE.includes(r.state) && r.condition) {  // the form shows the run that is going
    document.getElementById("condition").value = r.condition;
    document.getElementById("episodes").value = r.episodes;
  }
  showStudy(s.study);
  refreshBanner();
  updateControls(); drawMap(); drawVideo();  // a run's end shows at once, not at the next frame
}

// ----- col study: the protocol sets the condition and episodes; a questionnaire after each block
function showStudy(st) {
  C.study = st || null;
  document.getElementById("study-panel").classList.toggle("study-hidden", !st);
  if (!st) return;
  const next = st.next;
  setText("study-info", `participant ${st.participant}; conditions in the order ${st.order.join(", ")}; ` +
    (next ? `next: ${next.name} (${next.condition}, ${next.episodes} episodes)` : "the study is complete, thank you"));
  const list = document.getElementById("study-blocks");
  list.replaceChildren(...st.blocks.map((b) => {
    const li = document.createElement("li");
    li.textContent = `${b.name}: ${b.condition}, ${b.flown} of ${b.episodes} episodes - ${b.state}`;
    return li;
  }));
  if (next && !ACTIVE.includes(C.status.run.state)) {
    document.getElementById("condition").value = next.condition;
    document.getElementById("episodes").value = next.episodes;
  }
  document.getElementById("condition").disabled = true;
  document.getElementById("episodes").disabled = true;
  document.getElementById("tlx").classList.toggle("study-hidden", !st.questionnaire_for);
}

function tlxAnswers() {
  const answers = {};
  for (const el of document.querySelectorAll("#tlx input[data-scale]")) answers[el.dataset.scale] = Number(el.value);
  return answers;
}

function updateControls() {
  const st = runState(), pilot = isPilot(), active = ACTIVE.includes(st), offline = !C.connected;
  const last = C.records.length ? C.records[C.records.length - 1] : null;
  const hold = C.status && C.status.input.holding && C.status.input.hold_reason;
  const studyWaits = C.study && (!C.study.next || C.study.questionnaire_for);  // col study: finished, or the questionnaire first
  const enable = { start: pilot && !active && !studyWaits, go: pilot && st === "ready", pause: pilot && active && st !== "stopping",
    next: pilot && st === "running", stop: pilot && active && st !== "stopping", handback: pilot && !!hold,
    discard: pilot && !!last && !last.discarded && !["starting", "running", "stopping"].includes(st), auto: pilot };
  for (const [id, on] of Object.entries(enable)) document.getElementById(id).disabled = !on;
  document.getElementById("take-role").disabled = offline || (!pilot && C.role && C.role.pilot_page !== null);
  for (const id of ["condition", "episodes"]) document.getElementById(id).disabled = offline || !!C.study;
  for (const el of document.querySelectorAll("#tlx input, #tlx button")) el.disabled = offline;
}

function onStep(m) {
  if (C.trackEpisode !== m.episode) { C.track = []; C.trackEpisode = m.episode; }
  C.lastStep = m; lastStepAt = C.now();
  C.steps.push({ episode: m.episode, step: m.step, who: m.who, recorded: m.recorded, tag: m.tag,
    wallMs: m.wall_ms, forward: m.setpoint.forward_m_s, frame: m.frame_number, timeBootMs: m.time_boot_ms });
  if (C.steps.length > 20000) C.steps.splice(0, 10000);
  C.track.push({ n: m.position_ne_m[0], e: m.position_ne_m[1], who: m.who });
  if (m.who === "hold" || C.steps.length < 2 || C.steps[C.steps.length - 2].who === "hold") refreshBanner();
  drawMap(); drawInset();
  if (!lastFrame) drawVideo();
}

// ----- camera and HUD ----------------------------------------------------------------------
function onFrame(buf) {
  const dv = new DataView(buf);
  const header = { number: dv.getUint32(0, true), stampMs: dv.getUint32(4, true), sentMs: dv.getFloat64(8, true) };
  createImageBitmap(new Blob([buf.slice(16)], { type: "image/jpeg" })).then((bmp) => {
    frames.set(header.number, bmp);
    for (const n of frames.keys()) {
      if (frames.size <= FRAMES_KEPT) break;
      frames.get(n).close(); frames.delete(n);
    }
    lastFrame = { bitmap: bmp, header }; lastFrameAt = C.now();
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

function videoState() {
  if (C.link === "lost" || C.link === "gone") return "offline";
  const active = ACTIVE.includes(runState());
  if (!active) return lastFrame ? "idle" : "no-video";
  if (!lastFrame) return "waiting";
  return C.now() - lastFrameAt > STALE_MS ? "stale" : "live";
}

function banner(g, w, h, text, colour) {
  g.fillStyle = "rgba(0,0,0,0.6)"; g.fillRect(0, h / 2 - 30, w, 60);
  g.fillStyle = colour; g.font = "bold 22px sans-serif"; g.textAlign = "center";
  g.fillText(text, w / 2, h / 2 + 8); g.textAlign = "left";
}

function drawVideo() {
  const cv = document.getElementById("video"), g = cv.getContext("2d");
  const state = C.videoState = videoState();
  g.fillStyle = "#000"; g.fillRect(0, 0, cv.width, cv.height);
  if (lastFrame) {
    g.globalAlpha = state === "live" ? 1 : 0.35;
    g.drawImage(lastFrame.bitmap, 0, 0, cv.width, cv.height); g.globalAlpha = 1;
  }
  if (state === "offline") banner(g, cv.width, cv.height, `NO LINK TO THE CONSOLE${lastFrame ? ": the last frame it sent" : ""}`, "#ef5350");
  else if (state === "stale") banner(g, cv.width, cv.height, `VIDEO STALE: no frame for ${((C.now() - lastFrameAt) / 1000).toFixed(1)} s`, "#ffeb3b");
  else if (state === "idle") banner(g, cv.width, cv.height, "NO RUN: last frame of the previous run", "#bbb");
  else if (state === "no-video") banner(g, cv.width, cv.height, "NO VIDEO: no run", "#888");
  else if (state === "waiting") banner(g, cv.width, cv.height, "waiting for the camera", "#888");
  drawHud(g, cv.width, cv.height, state);
}

function fmt(x, digits) { const v = Math.abs(x) < 0.5 * 10 ** -digits ? 0 : x; return v.toFixed(digits); }
function signed(x, digits) { const t = fmt(x, digits); return (t.startsWith("-") ? "" : "+") + t; }

function padLine(s) {
  if (s.pad) return [s.pad.partial ? "PAD at the image edge" : "PAD seen", s.pad.partial ? "#ffeb3b" : "#00e676"];
  if (s.pad_fills_image) return ["PAD fills the image (too close to see whole)", "#ffeb3b"];
  return ["PAD not visible", "#ffeb3b"];
}

function drawHud(g, w, h, video) {
  const s = C.lastStep, active = ACTIVE.includes(runState());
  g.font = "bold 15px monospace"; g.textBaseline = "top";
  const line = (text, x, y, colour) => {
    g.fillStyle = "rgba(0,0,0,0.55)"; g.fillRect(x - 3, y - 2, g.measureText(text).width + 6, 19);
    g.fillStyle = colour || "#fff"; g.fillText(text, x, y);
  };
  if (video === "offline") { C.hudState = "offline"; line("NO LINK: who flies is unknown", 10, 10, "#bbb"); return; }
  const fresh = s && active && lastStepAt !== null && C.now() - lastStepAt <= STEP_STALE_MS;
  C.hudState = !active ? "idle" : (fresh ? "flying" : "no-step");
  if (!fresh) {
    const why = !active ? `IDLE: ${runState()}` : (s ? `no control step for ${((C.now() - lastStepAt) / 1000).toFixed(1)} s` : "waiting for the first control step");
    line(why, 10, 10, "#bbb");
    return;
  }
  if (s.pad && lastFrame && lastFrame.header.number === s.frame_number) drawPad(g, s, w / s.image_size_px[0], 0, 0);
  line(`HGT ${fmt(s.height_above_pad_m, 2)} m above pad   ALT ${fmt(s.altitude_m, 2)} m`, 10, 10);
  line(`VS  ${signed(s.climb_m_s, 2)} m/s   GS ${fmt(s.ground_speed_m_s, 2)} m/s`, 10, 32);
  line(`HDG ${String(Math.round(s.heading_deg) % 360).padStart(3, "0")}\u00b0 (image up = nose)`, 10, 54);
  const [padText, padColour] = padLine(s);
  line(padText, 10, 76, padColour);
  const who = { person: "PERSON FLIES", policy: "POLICY FLIES", hold: "HOLDING (no usable input)" }[s.who];
  g.font = "bold 20px sans-serif";
  line(who, w - g.measureText(who).width - 14, 10, COLOURS[s.who]);
  g.font = "bold 15px monospace";
  const loss = s.loss === null ? "-" : s.loss.toExponential(2);
  line(`time left ${fmt(s.time_left_s, 1)} s`, w - 170, 40);
  line(`episode ${s.episode}  ${s.phase}  step ${s.step}`, 10, h - 66);
  line(`policy v${s.policy_version === null ? "-" : s.policy_version}  loss ${loss}`, 10, h - 44);
  line(`human samples ${s.samples}  frames ${C.framesDrawn}`, 10, h - 22);
}

function drawPad(g, s, k, x0, y0) {
  g.strokeStyle = s.pad.partial ? "#ffeb3b" : "#00e676"; g.lineWidth = 2;
  const u = x0 + s.pad.u * k, v = y0 + s.pad.v * k;
  g.beginPath(); g.arc(u, v, s.pad.r * k, 0, 2 * Math.PI); g.stroke();
  g.beginPath(); g.moveTo(u - 8, v); g.lineTo(u + 8, v); g.moveTo(u, v - 8); g.lineTo(u, v + 8); g.stroke();
}

// The policy's view: the very frame the latest step's pad was detected in, with the detection.
function drawInset() {
  const cv = document.getElementById("inset"), g = cv.getContext("2d"), s = C.lastStep;
  g.fillStyle = "#000"; g.fillRect(0, 0, cv.width, cv.height);
  g.fillStyle = "#aab"; g.font = "11px sans-serif"; g.textBaseline = "top";
  if (!s || s.frame_number === null || s.frame_number === undefined) { g.fillText("the policy saw no frame", 6, 6); return; }
  const bmp = frames.get(s.frame_number);
  if (!bmp) { g.fillText(`frame ${s.frame_number} not received here`, 6, 6); return; }
  g.drawImage(bmp, 0, 0, cv.width, cv.height);
  if (s.pad) drawPad(g, s, cv.width / s.image_size_px[0], 0, 0);
  g.fillStyle = "rgba(0,0,0,0.55)"; g.fillRect(0, cv.height - 16, cv.width, 16);
  g.fillStyle = "#fff"; g.fillText(`policy's frame ${s.frame_number}, step ${s.step}`, 4, cv.height - 14);
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
  if (ACTIVE.includes(runState())) {  // no marker for a vehicle the console no longer flies
    const v = truth && truth.vehicle_ned ? truth.vehicle_ned : (C.lastStep ? [...C.lastStep.position_ne_m] : null);
    const yaw = truth && truth.attitude_rad ? truth.attitude_rad[2] : (C.lastStep ? C.lastStep.heading_deg * Math.PI / 180 : 0);
    if (v) drawArrow(g, X(v[1]), Y(v[0]), yaw);
  }
  g.fillStyle = "#aab"; g.font = "11px sans-serif"; g.textBaseline = "alphabetic"; g.fillText(`grid 1 m, N up`, 6, W - 8);
}

function drawArrow(g, x, y, yaw) {  // yaw 0 = north (up), clockwise
  g.save(); g.translate(x, y); g.rotate(yaw);
  g.fillStyle = "#fff"; g.beginPath(); g.moveTo(0, -10); g.lineTo(6, 7); g.lineTo(0, 3); g.lineTo(-6, 7); g.closePath(); g.fill();
  g.restore();
}

function drawPlot() {
  const cv = document.getElementById("plot"), g = cv.getContext("2d"), W = cv.width, H = cv.height;
  g.fillStyle = "#0f1215"; g.fillRect(0, 0, W, H);
  const recs = C.records, n = recs.length;
  if (!n) { g.fillStyle = "#889"; g.font = "12px sans-serif"; g.fillText("no finished episodes yet", 80, H / 2); return; }
  // "policy alone": Int episodes the policy flew without a takeover, ended by touchdown or timeout
  let alone = 0, aloneWins = 0; const rate = [], samples = [];
  recs.forEach((r) => {
    if (!r.discarded && r.phase === "intervention" && r.interventions === 0 && r.outcome !== "stopped" && r.success !== null) {
      alone += 1; aloneWins += r.success ? 1 : 0;
    }
    rate.push(alone ? aloneWins / alone : null); samples.push(r.dataset_size);
  });
  const maxS = Math.max(1, ...samples), X = (i) => 20 + (n === 1 ? 0.5 : i / (n - 1)) * (W - 40);
  const series = (vals, top, colour) => {
    g.strokeStyle = colour; g.fillStyle = colour; g.lineWidth = 2; g.beginPath();
    let started = false;
    vals.forEach((v, i) => {
      if (v === null) return;
      const y = H - 15 - (v / top) * (H - 30); started ? g.lineTo(X(i), y) : g.moveTo(X(i), y); started = true;
    });
    g.stroke();
    vals.forEach((v, i) => { if (v !== null) { g.beginPath(); g.arc(X(i), H - 15 - (v / top) * (H - 30), 3, 0, 2 * Math.PI); g.fill(); } });
  };
  series(rate, 1, "#66bb6a"); series(samples, maxS, "#ffca28");
  g.fillStyle = "#aab"; g.font = "11px sans-serif";
  g.fillText(alone ? `policy alone ${aloneWins}/${alone} landed` : "policy alone: none yet", 6, 12);
  g.fillText(`${samples[n - 1]} samples`, W - 80, 12);
}

function fillTable() {
  const body = document.querySelector("#episodes-table tbody");
  body.innerHTML = "";
  for (const r of C.records) {
    const tr = document.createElement("tr");
    if (r.discarded) tr.className = "discarded";
    const cells = [r.episode, r.phase, r.outcome, r.success === null ? "-" : (r.success ? "yes" : "no"), r.steps,
      r.human_samples, r.interventions, r.touchdown_distance_m === null ? "-" : r.touchdown_distance_m.toFixed(2),
      r.dataset_size, r.policy_version === null ? "-" : r.policy_version];
    for (const c of cells) { const td = document.createElement("td"); td.textContent = c; tr.appendChild(td); }
    const note = document.createElement("td"); note.className = "flag";
    note.textContent = [r.no_stick_input ? "no stick input" : "", r.discarded ? `discarded: ${r.discarded}` : ""].filter(Boolean).join("; ");
    tr.appendChild(note); body.appendChild(tr);
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
  if (p) {  // sent as the pad reports it: a pad with fewer axes or buttons is refused, never padded
    return { source: p.id || "gamepad", axes: Array.from(p.axes).slice(0, AXES_NEEDED),
      buttons: Array.from(p.buttons).map((b) => (typeof b === "object" ? b.value : Number(b))) };
  }
  // the keyboard is a whole pad: both sticks (4 axes) and 8 buttons, Space the trigger (button 7)
  const k = (a, b) => (keys.has(a) ? -KEY_STICK : 0) + (keys.has(b) ? KEY_STICK : 0);
  const buttons = new Array(BUTTONS_NEEDED).fill(0); buttons[7] = keys.has(" ") ? 1 : 0;
  return { source: "keyboard", axes: [k("a", "d"), k("w", "s"), k("ArrowLeft", "ArrowRight"), k("ArrowUp", "ArrowDown")], buttons };
}

const inField = () => ["INPUT", "SELECT", "TEXTAREA"].includes(document.activeElement.tagName);

let lastSent = { key: "", at: 0 };
function sendInput() {
  const inp = readInput(), now = performance.now();
  const key = JSON.stringify([inp.axes, inp.buttons[7]]);
  if (key === lastSent.key && now - lastSent.at < 1000 / SEND_HZ) return;
  lastSent = { key, at: now };
  let src = inp.source === "keyboard" ? (inField() ? "keyboard: typing in a form field (Space still overrides; click the video to fly)" : "no gamepad: keyboard") : `gamepad: ${inp.source}`;
  if (inp.source !== "keyboard" && (inp.axes.length < AXES_NEEDED || inp.buttons.length < BUTTONS_NEEDED)) {
    src += ` - reports ${inp.axes.length} axes and ${inp.buttons.length} buttons, not the standard layout: refused`;
  }
  setText("pad-state", isPilot() ? src : `${src} - ${C.connected ? "watching" : "not connected"}, not sent`);
  drawStick("stick-left", inp.axes[0], inp.axes[1]);
  drawStick("stick-right", inp.axes[2], inp.axes[3]);
  document.getElementById("trigger-bar").style.height = `${Math.round(100 * Math.min(1, Math.max(0, inp.buttons[7] || 0)))}%`;
  if (!isPilot()) return;
  send({ type: "input", axes: inp.axes, buttons: inp.buttons, seq: seq++, t: performance.timeOrigin + now });
  C.inputsSent += 1;
}

function drawStick(id, x, y) {
  const cv = document.getElementById(id), g = cv.getContext("2d"), c = cv.width / 2, reach = c - 9;
  const clamp = (v) => (Number.isFinite(v) ? Math.max(-1, Math.min(1, v)) : 0);
  g.clearRect(0, 0, cv.width, cv.height);
  if (C.hello) { const d = C.hello.deadband * reach; g.strokeStyle = "#333"; g.strokeRect(c - d, c - d, 2 * d, 2 * d); }
  g.fillStyle = Number.isFinite(x) && Number.isFinite(y) ? "#9fb3c8" : "#e53935";
  g.beginPath(); g.arc(c + clamp(x) * reach, c + clamp(y) * reach, 8, 0, 2 * Math.PI); g.fill();
}

// ----- page furniture ----------------------------------------------------------------------
function setText(id, text) { document.getElementById(id).textContent = text; }
function setLink() {
  const b = document.getElementById("link");
  b.textContent = { open: "connected", lost: "link lost: reconnecting", gone: "no console", connecting: "connecting" }[C.link];
  b.className = `badge ${C.link === "open" ? "ok" : "bad"}`;
}
function showBanner(text, kind) { const b = document.getElementById("banner"); b.textContent = text; b.className = `banner ${kind || ""}`; C.banner = text; }
function hideBanner() { document.getElementById("banner").className = "banner hidden"; C.banner = ""; }

// Errors stay until the person dismisses them; the same error again counts up instead of piling up.
// The server counts its refusals (``count``: how often this page's messages were refused for that
// reason; a run of them is told at most twice a second); the page's own errors count here.
function addError(text, count) {
  const same = C.errors.find((e) => e.text === text && !e.dismissed);
  const entry = same || { text, count: 0, el: document.createElement("div"), dismissed: false };
  entry.count = Number.isInteger(count) ? Math.max(count, entry.count) : entry.count + 1;
  if (!same) {
    const span = document.createElement("span"), close = document.createElement("button");
    close.textContent = "Dismiss";
    close.onclick = () => { entry.dismissed = true; entry.el.remove(); };
    entry.el.className = "error"; entry.el.append(span, close);
    document.getElementById("errors").appendChild(entry.el); C.errors.push(entry);
  }
  entry.el.querySelector("span").textContent = entry.count > 1 ? `${text} (x${entry.count})` : text;
}

window.addEventListener("keydown", (e) => {
  if (e.key === " ") {  // the override works wherever the focus is (and never presses a focused button)
    e.preventDefault(); if (inField() || document.activeElement.tagName === "BUTTON") document.activeElement.blur();
    keys.add(" "); return;
  }
  if (inField()) return;
  keys.add(e.key.length === 1 ? e.key.toLowerCase() : e.key);
  if (e.key.startsWith("Arrow")) e.preventDefault();
});
window.addEventListener("keyup", (e) => keys.delete(e.key.length === 1 ? e.key.toLowerCase() : e.key));
window.addEventListener("blur", () => keys.clear());
document.getElementById("start").onclick = () => {
  const text = document.getElementById("episodes").value.trim(), episodes = Number(text);
  if (!/^\d+$/.test(text) || !Number.isInteger(episodes) || episodes < 1 || episodes > 1000) {
    addError(`episodes must be a whole number from 1 to 1000, not "${text}"`); return;
  }
  command("start", { condition: document.getElementById("condition").value, episodes, auto: document.getElementById("auto").checked });
};
document.getElementById("go").onclick = () => command("go");
document.getElementById("auto").onchange = (e) => { if (ACTIVE.includes(runState())) command("auto", { on: e.target.checked }); };
document.getElementById("pause").onclick = () => command(C.status && C.status.run.paused ? "resume" : "pause");
document.getElementById("next").onclick = () => command("next");
document.getElementById("stop").onclick = () => command("stop");
document.getElementById("handback").onclick = () => command("hand_back");
document.getElementById("discard").onclick = () => {
  const last = C.records[C.records.length - 1];
  if (last && window.confirm(`Take episode ${last.episode} out of training? Its samples stay in human.csv, listed in human.discarded.jsonl.`)) {
    command("discard_last", { reason: last.no_stick_input ? "demonstration with no stick input" : "discarded by the pilot" });
  }
};
document.getElementById("tlx-submit").onclick = () => command("questionnaire", { answers: tlxAnswers() });
document.getElementById("tlx-skip").onclick = () => command("questionnaire", { skip: true });
document.getElementById("take-role").onclick = () => send({ type: "role", want: isPilot() ? "watch" : "pilot" });

connect();
setInterval(sendInput, POLL_MS);
setInterval(drawVideo, 200);  // the stale / idle state shows even when no frame arrives
drawVideo(); drawMap(); drawPlot(); updateControls();
