// JSAR web ground station: the page. Plain JS, no build step.
// Video: binary WebSocket messages, each a preview sample as the daemon sent it (32-byte little-endian
// header "JFR1" "JPEG" width height frame_id capture_time, then the JPEG). The box drawn on a frame is the
// one of that frame's own track sample (same frame_id), never a newer or older one.
// Commands: click = track point, drag = track rectangle, Stop button / Escape = stop tracking (only while
// there is a track to stop); coordinates normalised 0..1 from the image's top-left corner, sent to the
// selected drone's camera over MAVLink.
// Confidence: the station reads each track sample's raw score as a percentage of the best score of the
// current lock (gcs/confidence.py); below its bar the box is drawn amber, "low confidence", even while the
// daemon still reports tracking.
"use strict";

const HEADER_BYTES = 32;
const TRACK_KEEP = 600;           // track samples kept by frame id (20 s at 30 fps)
const DRAG_MIN_PX = 8;            // a press that moves less than this (CSS px) is a click
const POINT_RADIUS_PX = 20;       // QGroundControl's click radius, as a fraction of the shown width
const COLOURS = { tracking: "#2ecc40", low: "#ffb000", coasting: "#ffb000", lost: "#ff3b30" };

const canvas = document.getElementById("video");
const ctx = canvas.getContext("2d");
const el = (id) => document.getElementById(id);

const view = {                    // what the page shows; window.gcsView for tests and the curious
  prefix: null, frameId: null, captureTime: null, frameSize: null, box: null, state: null, coasting: false,
  score: null, confidence: null, lowConfidence: false, boxColour: null, boxLabel: null, drawnFrames: 0,
  framesWithBox: 0, lowConfidenceFrames: 0, status275: null, lastAck: null, drones: [], autopilot: null,
};
window.gcsView = view;

let socket = null;
let reconnectMs = 500;
let bitmap = null;                // the frame on screen
let decodingId = -1;              // newest frame id handed to the decoder
const tracks = new Map();         // frame_id -> {sample, confidence} (watched drone)
let latestTrack = null;
let drag = null;                  // {x0, y0, x1, y1} in normalised coordinates while the mouse is down
let nextCommandId = 1;
let frameTimes = [];

// ----- connection ------------------------------------------------------------------------------
function connect() {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  socket = new WebSocket(`${scheme}://${location.host}/ws`);
  socket.binaryType = "arraybuffer";
  socket.onopen = () => {
    reconnectMs = 500;
    setText("connection", "connected", "good");
    if (view.prefix) send({ type: "watch", prefix: view.prefix });
  };
  socket.onclose = () => {
    setText("connection", "disconnected: reconnecting…", "bad");
    setTimeout(connect, reconnectMs);
    reconnectMs = Math.min(reconnectMs * 2, 5000);
  };
  socket.onmessage = (event) => {
    if (typeof event.data === "string") onJson(JSON.parse(event.data));
    else onFrame(event.data);
  };
}

function send(message) {
  if (socket && socket.readyState === WebSocket.OPEN) {
    socket.send(JSON.stringify(message));
    return true;
  }
  return false;
}

// ----- messages from the server ----------------------------------------------------------------
function onJson(message) {
  if (message.type === "drones") onDrones(message.drones, message.complete);
  else if (message.type === "events") message.events.forEach(onEvent);
}

function onEvent(event) {
  if (event.type === "drones") { onDrones(event.drones, event.complete); return; }
  if (event.prefix !== view.prefix) return;  // from before the operator switched drones
  if (event.type === "track") onTrack(event.sample, event.confidence);
  else if (event.type === "status275") onStatus275(event.status);
  else if (event.type === "ack") onAck(event);
  else if (event.type === "text") addMessage(event.text, event.severity <= 4 ? "warn" : "");
}

function onDrones(drones, complete) {
  view.drones = drones;
  const list = el("drones");
  list.replaceChildren();
  el("drones-empty").style.display = drones.length ? "none" : "";
  for (const drone of drones) {
    const item = document.createElement("li");
    const button = document.createElement("button");
    button.type = "button";
    button.dataset.prefix = drone.prefix;
    button.className = drone.prefix === view.prefix ? "selected" : "";
    const dot = document.createElement("span");
    dot.className = "dot " + stateClass(drone.state, drone.coasting);
    const name = document.createElement("span");
    name.className = "name";
    name.append(dot, drone.prefix);
    const detail = document.createElement("span");
    detail.className = "detail";
    const ident = drone.system_id == null ? "MAVLink id unknown" : `sys ${drone.system_id} comp ${drone.component_id}`;
    const problems = [];
    if (!drone.online) problems.push("offline");
    if (drone.autopilot && drone.autopilot.state !== "connected") problems.push("no autopilot");
    if (drone.system_id != null && !drone.mavlink_heard) problems.push("not heard on MAVLink");
    if (drone.conflict) problems.push("MAVLink id clash");
    detail.textContent = `${drone.state || "–"} · ${ident}${problems.length ? " · " + problems.join(", ") : ""}`;
    button.append(name, detail);
    button.onclick = () => select(drone.prefix);
    item.append(button);
    list.append(item);
  }
  // one drone on the whole network (not merely the first to answer): nothing to choose
  if (!view.prefix && complete && drones.length === 1) select(drones[0].prefix);
  const current = drones.find((d) => d.prefix === view.prefix);
  if (current) {
    showAutopilot(current.autopilot);
    setText("mavlink-id", current.system_id == null ? "unknown (status not answered yet)"
      : `system ${current.system_id}, component ${current.component_id}` +
        (current.mavlink_heard ? "" : " (not heard on MAVLink)") + (current.conflict ? " (id clash!)" : ""),
      current.system_id != null && current.mavlink_heard && !current.conflict ? "" : "warn");
  }
}

function select(prefix) {
  if (prefix === view.prefix) return;
  view.prefix = prefix;
  tracks.clear();
  latestTrack = null;
  bitmap = null;
  decodingId = -1;
  frameTimes = [];
  Object.assign(view, { frameId: null, captureTime: null, frameSize: null, box: null, state: null,
    coasting: false, score: null, confidence: null, lowConfidence: false, status275: null, lastAck: null,
    autopilot: null });
  for (const id of ["state", "confidence", "status275", "ack", "latency", "video-info", "mavlink-id", "autopilot",
    "gimbal"]) setText(id, "–");
  setText("score", "");
  showConfidence(null, null);
  el("video-warning").textContent = "";
  updateStop(null);
  el("messages").replaceChildren();
  setText("drone-name", prefix);
  el("video-note").textContent = "Waiting for video…";
  document.querySelectorAll("#drones button").forEach((b) => b.classList.toggle("selected", b.dataset.prefix === prefix));
  send({ type: "watch", prefix });
  draw();
}

function onTrack(sample, confidence) {
  tracks.set(sample.frame_id, { sample, confidence });
  if (tracks.size > TRACK_KEEP) tracks.delete(tracks.keys().next().value);
  if (latestTrack && sample.frame_id < latestTrack.frame_id) return;  // an older sample: the panel shows the newest
  latestTrack = sample;
  const cls = stateClass(sample.state, sample.coasting, confidence);
  const stateText = sample.state + (sample.state === "lost" && sample.coasting ? " (coasting)" : "") +
    (cls === "low" ? " (low confidence)" : "");
  setText("state", stateText, { tracking: "good", low: "warn", coasting: "warn", lost: "bad" }[cls] || "");
  showConfidence(sample, confidence);
  const latency = sample.latency_ms || {};
  setText("latency", latency.total == null ? "–" : `${latency.total.toFixed(1)} ms`);
  updateStop(sample.state);
  if (sample.frame_id === view.frameId) draw();  // the box of the frame on screen arrived after it
}

// The confidence row: a bar (the mark at the low-confidence bar) and "N % of this lock's best", the raw
// score beside it, small.
function showConfidence(sample, confidence) {
  const fill = el("confidence-fill");
  if (!sample || !confidence) {
    fill.style.width = "0";
    setText("confidence", sample && sample.state !== "idle" ? "no score" : "–", "");
    setText("score", sample && sample.score != null ? `raw score ${sample.score.toFixed(3)}` : "");
    return;
  }
  const lost = sample.state === "lost";
  const cls = lost ? "bad" : confidence.low ? "warn" : "good";
  fill.style.width = `${confidence.percent}%`;
  fill.className = cls;
  el("confidence-mark").style.left = `${Math.round(100 * confidence.low_below)}%`;
  setText("confidence", `${confidence.percent} % of this lock's best` +
    (lost ? " (lost)" : confidence.low ? " · low confidence" : ""), cls);
  setText("score", `raw score ${sample.score.toFixed(3)}`);
}

// The autopilot and gimbal rows, from the daemon's status answer (gcs/drones.py autopilot_summary), and a
// warning across the video when no autopilot takes the gimbal commands.
function showAutopilot(ap) {
  view.autopilot = ap;
  let text = "unknown (status not answered yet)", cls = "", gimbal = "–", gimbalCls = "";
  if (ap) {
    if (ap.state === "connected") { text = `connected (system ${ap.system_id})`; cls = "good"; }
    else if (ap.state === "heartbeat_lost") { text = `heartbeat lost (system ${ap.system_id}) — gimbal and guidance held`; cls = "bad"; }
    else if (ap.gimbal_commands === "held") { text = "none — gimbal commands held"; cls = "bad"; }
    else { text = `none heard — commands sent to system ${ap.configured_system_id} unanswered`; cls = "bad"; }
    if (ap.gimbal_commands === "none") { gimbal = "none configured (gimbal.backend: none)"; gimbalCls = "warn"; }
    else if (ap.gimbal_commands === "held") { gimbal = `${ap.gimbal_backend} — commands held (${ap.state === "heartbeat_lost" ? "autopilot silent" : "no autopilot"})`; gimbalCls = "bad"; }
    else { gimbal = `${ap.gimbal_backend} gimbal manager, through the autopilot`; gimbalCls = ap.state === "connected" ? "" : "warn"; }
    // whether a gimbal device has reported its attitude: commands to a gimbal that never answered move nothing
    if (ap.gimbal_commands === "sent" && ap.gimbal_attitude === true) gimbal += " · attitude reported";
    else if (ap.gimbal_commands === "sent" && ap.gimbal_attitude === false) {
      gimbal += " · no gimbal attitude heard"; if (!gimbalCls) gimbalCls = "warn";
    }
  }
  setText("autopilot", text, cls);
  setText("gimbal", gimbal, gimbalCls);
  el("video-warning").textContent = ap && ap.state !== "connected" ? `autopilot: ${text}` : "";
}

// Stop is offered only while there is a track to stop (the daemon reports tracking or lost).
function updateStop(state) {
  el("stop").disabled = !(view.prefix && (state === "tracking" || state === "recovered" || state === "lost"));
}

function onStatus275(status) {
  view.status275 = status;
  const rect = status.rectangle.every((v) => v != null)
    ? ` (${status.rectangle.map((v) => v.toFixed(2)).join(", ")})` : "";
  setText("status275", `${status.status_name} · ${status.mode}${rect}`,
    status.status_name.includes("ERROR") ? "bad" : status.status_name.includes("COASTING") ? "warn"
      : status.status_name.startsWith("ACTIVE") ? "good" : "");
}

function onAck(ack) {
  view.lastAck = ack;
  const text = `${ack.command}: ${ack.result_name}` + (ack.reason ? ` (${ack.reason})` : "") +
    (ack.attempts > 1 ? ` after ${ack.attempts} tries` : "");
  setText("ack", text, ack.result_name === "ACCEPTED" ? "good" : "bad");
  addMessage(text, ack.result_name === "ACCEPTED" ? "" : "bad");
}

// ----- video -----------------------------------------------------------------------------------
function onFrame(buffer) {
  if (buffer.byteLength < HEADER_BYTES) return;
  const header = new DataView(buffer, 0, HEADER_BYTES);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  const format = String.fromCharCode(...new Uint8Array(buffer, 4, 4));
  if (magic !== "JFR1" || format !== "JPEG") return;
  const width = header.getUint32(8, true);
  const height = header.getUint32(12, true);
  const frameId = Number(header.getBigUint64(16, true));
  const captureTime = header.getFloat64(24, true);
  if (frameId <= decodingId) return;
  decodingId = frameId;
  const prefix = view.prefix;
  createImageBitmap(new Blob([buffer.slice(HEADER_BYTES)], { type: "image/jpeg" })).then((image) => {
    if (prefix !== view.prefix || frameId < (view.frameId ?? -1)) { image.close(); return; }
    if (bitmap) bitmap.close();
    bitmap = image;
    view.frameId = frameId;
    view.captureTime = captureTime;
    view.frameSize = [width, height];
    const now = performance.now();
    frameTimes.push(now);
    while (frameTimes.length && now - frameTimes[0] > 2000) frameTimes.shift();
    setText("video-info", `${width}×${height}, ${(frameTimes.length / 2).toFixed(1)} fps, frame ${frameId}`);
    el("video-note").textContent = "";
    draw();
  }).catch(() => { /* a frame that does not decode is skipped; the next one replaces it */ });
}

function stateClass(state, coasting, confidence) {
  if (state === "lost") return coasting ? "coasting" : "lost";
  if (state === "tracking" || state === "recovered") return confidence && confidence.low ? "low" : "tracking";
  return "idle";
}

function draw() {
  if (!bitmap) {
    ctx.fillStyle = "#000";
    ctx.fillRect(0, 0, canvas.width, canvas.height);
  } else {
    if (canvas.width !== bitmap.width || canvas.height !== bitmap.height) {
      canvas.width = bitmap.width;
      canvas.height = bitmap.height;
    }
    ctx.drawImage(bitmap, 0, 0);
  }
  const W = canvas.width, H = canvas.height;
  const scale = Math.max(1, W / 640);
  const entry = view.frameId == null ? null : tracks.get(view.frameId);
  const sample = entry ? entry.sample : null;
  const confidence = entry ? entry.confidence : null;
  view.box = null;
  view.boxColour = null;
  view.boxLabel = null;
  view.state = sample ? sample.state : null;
  view.coasting = sample ? !!sample.coasting : false;
  view.score = sample ? sample.score : null;
  view.confidence = confidence ? confidence.percent : null;
  view.lowConfidence = !!(sample && stateClass(sample.state, sample.coasting, confidence) === "low");
  if (sample && sample.box_norm && sample.state !== "idle") {
    const [x, y, w, h] = sample.box_norm;
    const cls = stateClass(sample.state, sample.coasting, confidence);
    ctx.strokeStyle = COLOURS[cls] || "#ffffff";
    ctx.lineWidth = 2 * scale;
    if (cls === "coasting" || cls === "lost") ctx.setLineDash([6 * scale, 4 * scale]);  // dashed: lost
    ctx.strokeRect(x * W, y * H, w * W, h * H);
    ctx.setLineDash([]);
    const name = { coasting: "lost, coasting", low: "low confidence", tracking: sample.state }[cls] || sample.state;
    const label = name + (confidence && cls !== "lost" && cls !== "coasting" ? ` ${confidence.percent} %` : "");
    ctx.font = `${Math.round(13 * scale)}px system-ui, sans-serif`;
    const tw = ctx.measureText(label).width + 8 * scale;
    const ty = y * H > 20 * scale ? y * H - 18 * scale : (y + h) * H + 2 * scale;
    ctx.fillStyle = "rgba(0,0,0,0.6)";
    ctx.fillRect(x * W, ty, tw, 16 * scale);
    ctx.fillStyle = COLOURS[cls] || "#ffffff";
    ctx.fillText(label, x * W + 4 * scale, ty + 12 * scale);
    view.box = [x, y, w, h];
    view.boxColour = COLOURS[cls] || "#ffffff";
    view.boxLabel = label;
    view.framesWithBox += 1;
    if (cls === "low") view.lowConfidenceFrames += 1;
  }
  if (drag) {
    ctx.strokeStyle = "#4ea1ff";
    ctx.lineWidth = 1.5 * scale;
    ctx.setLineDash([4 * scale, 3 * scale]);
    const x0 = Math.min(drag.x0, drag.x1), y0 = Math.min(drag.y0, drag.y1);
    ctx.strokeRect(x0 * W, y0 * H, Math.abs(drag.x1 - drag.x0) * W, Math.abs(drag.y1 - drag.y0) * H);
    ctx.setLineDash([]);
  }
  if (bitmap) view.drawnFrames += 1;
}

// ----- operator input --------------------------------------------------------------------------
function normalised(event) {
  const r = canvas.getBoundingClientRect();
  return { x: clamp01((event.clientX - r.left) / r.width), y: clamp01((event.clientY - r.top) / r.height),
           px: event.clientX, py: event.clientY, width: r.width };
}
const clamp01 = (v) => Math.min(1, Math.max(0, v));

canvas.addEventListener("mousedown", (event) => {
  if (event.button !== 0) return;
  const p = normalised(event);
  drag = { x0: p.x, y0: p.y, x1: p.x, y1: p.y, px: p.px, py: p.py, moved: false };
  canvas.focus();
});
canvas.addEventListener("mousemove", (event) => {
  if (!drag) return;
  const p = normalised(event);
  drag.x1 = p.x; drag.y1 = p.y;
  if (Math.hypot(p.px - drag.px, p.py - drag.py) >= DRAG_MIN_PX) drag.moved = true;
  draw();
});
window.addEventListener("mouseup", (event) => {
  if (!drag) return;
  const d = drag;
  drag = null;
  draw();
  if (!view.prefix) { addMessage("pick a drone first", "warn"); return; }
  if (d.moved) {
    command({ type: "rect", x0: Math.min(d.x0, d.x1), y0: Math.min(d.y0, d.y1),
              x1: Math.max(d.x0, d.x1), y1: Math.max(d.y0, d.y1) });
  } else {
    const r = canvas.getBoundingClientRect();
    command({ type: "point", x: d.x0, y: d.y0, radius: POINT_RADIUS_PX / r.width });
  }
});
el("stop").addEventListener("click", () => stop());
window.addEventListener("keydown", (event) => {
  if (event.key === "Escape") {
    if (drag) { drag = null; draw(); return; }  // Escape first cancels a drag in progress
    stop();
  }
});

function stop() {
  if (!view.prefix) { addMessage("pick a drone first", "warn"); return; }
  if (el("stop").disabled) { addMessage("no track to stop", ""); return; }
  command({ type: "stop" });
}

function command(message) {
  const full = { ...message, prefix: view.prefix, id: nextCommandId++ };
  const name = { point: "TRACK_POINT", rect: "TRACK_RECTANGLE", stop: "STOP_TRACKING" }[message.type];
  if (send(full)) setText("ack", `${name}: sent, waiting for the ACK…`, "");
  else setText("ack", `${name}: not sent (no connection to the station)`, "bad");
}

// ----- small helpers ---------------------------------------------------------------------------
function setText(id, text, cls) {
  const node = el(id);
  node.textContent = text;
  if (cls !== undefined) node.className = cls;
}

function addMessage(text, cls) {
  const item = document.createElement("li");
  item.textContent = `${new Date().toLocaleTimeString()} ${text}`;
  if (cls) item.className = cls;
  const list = el("messages");
  list.prepend(item);
  while (list.children.length > 30) list.lastChild.remove();
}

// A stalled video says so (the last frame stays on screen, marked), instead of looking live.
setInterval(() => {
  if (!view.prefix || !bitmap || !frameTimes.length) return;
  const age = (performance.now() - frameTimes[frameTimes.length - 1]) / 1000;
  el("video-note").textContent = age > 2 ? `No video for ${age.toFixed(0)} s` : "";
}, 500);

draw();
connect();
