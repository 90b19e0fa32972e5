// Operator UI: live feed over /ws/operator, commands and settings over the HTTP API.
"use strict";

const $ = id => document.getElementById(id);
const TOKEN = new URLSearchParams(location.search).get("token") || ""; // needed when the station has --token
const withToken = url => TOKEN ? url + (url.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(TOKEN) : url;
const state = { config: null, live: {}, selected: null, trajectories: {} };
window.evp = state; // for tests and the curious

function selectedTrajectory() { return state.trajectories[state.selected] || []; }

function redraw() {
  const poses = selectedTrajectory().filter(p => p.state === "OK" || p.state === "RELOCALIZED");
  const plane = $("plane").value;
  const top = poses.map(p => plane === "xy" ? [p.t[0], p.t[1]] : [p.t[0], p.t[2]]);
  const up = poses.map(p => [p.timestamp, plane === "xy" ? -p.t[2] : -p.t[1]]);
  plotLine($("top-view"), top, plane === "xy" ? ["x", "y"] : ["x", "z"], true);
  plotLine($("altitude"), up, ["time (s)", plane === "xy" ? "altitude (−z)" : "altitude (−y)"], false);
}

function showPose(pose) {
  const f = v => v.toFixed(3);
  $("pose").textContent = `seq ${pose.seq}  t=${pose.timestamp.toFixed(3)} s  ${pose.state}  quality ${pose.quality}  ` +
    `t=(${pose.t.map(f).join(", ")})  q(w,x,y,z)=(${pose.q.map(f).join(", ")})`;
}

function addEvent(e) {
  const line = document.createElement("div");
  line.className = "event " + e.level;
  const when = new Date(e.t * 1000).toLocaleTimeString();
  line.textContent = `${when} ${e.level.toUpperCase()} ${e.session_id ? e.session_id + " " : ""}[${e.code}] ${e.text}`;
  const log = $("event-log");
  log.appendChild(line);
  while (log.childNodes.length > 500) log.removeChild(log.firstChild);
  log.scrollTop = log.scrollHeight;
}

function refreshSelect() {
  const select = $("session-select"), ids = Object.keys(state.live);
  if (!state.selected || !state.live[state.selected]) state.selected = ids[ids.length - 1] || null;
  select.innerHTML = "";
  for (const id of ids) {
    const option = document.createElement("option");
    option.value = id; option.textContent = `${id} (${state.live[id].device || "mobile"}${state.live[id].connected ? "" : ", offline"})`;
    option.selected = id === state.selected;
    select.appendChild(option);
  }
  updateStatusBar();
}

function updateStatusBar() {
  const live = state.live[state.selected];
  $("st-comm").textContent = live ? (live.connected ? "connected" : "disconnected") : "no mobile station";
  const s = live && live.status;
  $("st-state").textContent = s ? s.state : "idle";
  $("st-fps").textContent = s ? s.fps.toFixed(1) : "0";
  $("st-latency").textContent = s && s.latency_ms_p50 ? s.latency_ms_p50.toFixed(0) + " ms" : "–";
  $("st-dropped").textContent = s ? String(s.frames_dropped) : "0";
}

function fillSettings(config) {
  state.config = config;
  for (const [key, value] of Object.entries(config.orb || {})) $("orb-form").elements[key].value = value;
  const form = $("camera-form").elements;
  for (const [key, value] of Object.entries(config.camera || {})) if (form[key]) form[key].value = value;
  form.fps.value = config.fps; form.color_space.value = config.color_space;
}

async function loadSessions() {
  const response = await fetch(withToken("/api/sessions"));
  const body = await response.json();
  const tbody = document.querySelector("#sessions tbody");
  tbody.innerHTML = "";
  for (const s of body.sessions) {
    const row = tbody.insertRow();
    for (const value of [s.id, s.device, s.status, s.frames_received, s.frames_estimated, s.frames_dropped]) row.insertCell().textContent = value;
    row.insertCell().innerHTML = `<a href="${withToken(`/api/sessions/${s.id}/trajectory.tum`)}">TUM</a> · <a href="${withToken(`/api/sessions/${s.id}/recording.mcap`)}">MCAP</a>`;
  }
}

function onMessage(message) {
  switch (message.type) {
    case "snapshot": {
      const link = message.link;
      $("phone-url").textContent = $("phone-url").href = link.phone_url || "";
      $("mobile-url").textContent = link.mobile_ws_url || "";
      $("fingerprint").textContent = link.fingerprint_sha256 || "(no TLS)";
      $("token").textContent = link.token_required ? "required (in the phone page address)" : "none";
      $("mavlink").textContent = message.mavlink || "off";
      $("data-dir").textContent = message.data_dir; $("db").textContent = message.db;
      fillSettings(message.config);
      state.live = message.live; refreshSelect(); loadSessions();
      break;
    }
    case "pose": {
      const list = state.trajectories[message.session_id] = state.trajectories[message.session_id] || [];
      list.push(message.pose);
      if (!state.live[message.session_id]) { state.live[message.session_id] = { connected: true }; refreshSelect(); }
      if (message.session_id === state.selected) { showPose(message.pose); redraw(); }
      break;
    }
    case "event": addEvent(message.event); if (["connected", "ended", "interrupted", "resumed"].includes(message.event.code)) loadSessions(); break;
    case "status":
      state.live[message.session_id] = Object.assign(state.live[message.session_id] || {}, { status: message.status, connected: message.connected });
      if (!$("session-select").querySelector(`option[value="${message.session_id}"]`)) refreshSelect(); else updateStatusBar();
      break;
    case "sessions": loadSessions(); break;
    case "config": fillSettings(message.config); break;
  }
}

function connect() {
  const socket = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + withToken("/ws/operator"));
  socket.onopen = () => { $("st-link").textContent = "up"; };
  socket.onclose = () => { $("st-link").textContent = "down (retrying)"; setTimeout(connect, 1000); };
  socket.onmessage = event => onMessage(JSON.parse(event.data));
}

async function command(action) {
  if (!state.selected) return;
  const response = await fetch(withToken(`/api/sessions/${state.selected}/${action}`), { method: "POST" });
  if (!response.ok) addEvent({ t: Date.now() / 1000, level: "error", code: action, text: (await response.json()).error, session_id: state.selected });
  if (action === "start") state.trajectories[state.selected] = [];
}

async function configure() {
  const orb = {}, camera = {};
  for (const input of $("orb-form").elements) orb[input.name] = Number(input.value);
  const form = $("camera-form").elements;
  for (const key of ["width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]) camera[key] = Number(form[key].value);
  const body = { orb, camera, fps: Number(form.fps.value), color_space: form.color_space.value };
  const response = await fetch(withToken("/api/configure"), { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
  const result = await response.json();
  $("configure-result").textContent = response.ok ? "stored and sent to the mobile stations" : "refused: " + result.error;
}

$("qr").src = withToken("/api/qr.svg");
$("camera-button").onclick = () => $("camera-dialog").showModal();
$("configure").onclick = configure;
$("start").onclick = () => command("start");
$("stop").onclick = () => command("stop");
$("resume").onclick = () => command("resume");
$("plane").onchange = redraw;
$("session-select").onchange = event => { state.selected = event.target.value; updateStatusBar(); redraw(); };
redraw();
connect();
