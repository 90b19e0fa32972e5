// Operator UI: live feed over /ws/operator, commands and settings over the HTTP API.
"use strict";

const $ = id => document.getElementById(id);
// per session: its poses and GPS fixes (decimated: a 2-hour session draws as fast as a short one),
// the navigation filter's last state and the GPS alarm in force
// and the station's background image for georeferenced top views ({image, bounds_deg}, once loaded)
const state = { config: null, live: {}, selected: null, trajectories: {}, gps: {}, navigation: {}, alarms: {}, background: null };
window.evp = state; // for tests and the curious
const ALARMS = { spoofing_alarm: "GPS SPOOFING SUSPECTED: position from vision", gps_lost: "GPS LOST (jamming or outage): position from vision" };
const series = (store, id) => (store[id] = store[id] || new DecimatedSeries());

// metres east and north of `origin` ([lat, lon] in degrees): local tangent plane, enough for a plot
function eastNorth(origin, lat, lon) {
  const R = 6378137, k = Math.PI / 180;
  return [(lon - origin[1]) * k * R * Math.cos(origin[0] * k), (lat - origin[0]) * k * R];
}

function redraw() {
  const poses = series(state.trajectories, state.selected).points;
  const tracked = poses.filter(p => p.metric || p.state === "OK" || p.state === "RELOCALIZED");
  const fixes = series(state.gps, state.selected).points;
  const georeferenced = tracked.filter(p => p.latitude_deg !== null && p.latitude_deg !== undefined);
  const plane = $("plane").value;
  if (georeferenced.length) { // the fused track (against GPS when there is any), east-north at the first fix or pose
    const first = fixes.length ? fixes[0] : georeferenced[0], origin = [first.latitude_deg, first.longitude_deg];
    const lines = [{ points: georeferenced.map(p => eastNorth(origin, p.latitude_deg, p.longitude_deg)), color: "#1565c0", label: "fused" }];
    if (fixes.length) lines.push({ points: fixes.map(f => eastNorth(origin, f.latitude_deg, f.longitude_deg)), color: "#ef6c00", label: "GPS" });
    const options = { equal: true, unit: "m" };
    if (state.background) {
      const [south, west, north, east] = state.background.bounds_deg;
      options.background = { image: state.background.image, corners: [eastNorth(origin, south, west), eastNorth(origin, north, east)] };
    }
    plotLines($("top-view"), lines, ["east (m)", "north (m)"], options);
  } else {
    // a monocular map has no metric scale until the navigation filter gives it one: say so in the units
    const metricTop = tracked.length > 0 && tracked[tracked.length - 1].metric, unit = metricTop ? "m" : "map units";
    const top = tracked.map(p => plane === "xy" ? [p.t[0], p.t[1]] : [p.t[0], p.t[2]]);
    plotLine($("top-view"), top, plane === "xy" ? [`x (${unit})`, `y (${unit})`] : [`x (${unit})`, `z (${unit})`], { equal: true, unit });
  }
  const metric = tracked.length && tracked[tracked.length - 1].metric;
  const up = tracked.map(p => [p.timestamp, metric || plane === "xy" ? (p.metric ? p.t[2] : -p.t[2]) : -p.t[1]]);
  plotLine($("altitude"), up, ["time (s)", metric ? "altitude (m)" : plane === "xy" ? "height, −z (map units)" : "height, −y (map units)"], {});
}

let redrawPending = false;
function scheduleRedraw() { // at most one redraw per animation frame, however fast the poses come
  if (redrawPending) return;
  redrawPending = true;
  requestAnimationFrame(() => { redrawPending = false; redraw(); });
}

// The navigation banner: the GPS alarm in force, else the GPS state and the alignment phase.
function updateBanner() {
  const banner = $("nav-banner"), id = state.selected;
  const nav = state.navigation[id], alarm = state.alarms[id];
  const poses = series(state.trajectories, id).points;
  const last = poses[poses.length - 1];
  const gps = (last && last.gps) || (nav && nav.gps) || "none";
  banner.dataset.gps = gps;
  banner.className = alarm ? "banner alarm" : gps === "trusted" ? "banner ok" : "banner";
  if (alarm) { banner.textContent = alarm; return; }
  const parts = [];
  if (nav) parts.push(nav.running ? "navigation filter running" : "navigation: " + nav.status);
  else if (last) parts.push(last.metric ? "navigation filter running" : "no navigation filter (no IMU extrinsic)");
  const a = nav && nav.alignment;
  if (gps === "aligning" && a) parts.push(`GPS alignment: ${a.pairs} fixes, spread ${a.spread_m.toFixed(1)} of ${a.needed_m.toFixed(0)} m`);
  else if (gps !== "none") parts.push("GPS " + gps + (a && a.model ? ` (${a.model}, residual ${a.residual_m.toFixed(2)} m)` : ""));
  if (last && last.visual_age_s !== null && last.visual_age_s !== undefined) parts.push(`vision ${(last.visual_age_s * 1000).toFixed(0)} ms ago`);
  banner.textContent = parts.join(" · ") || "no navigation yet";
}

function showPose(pose) {
  const f = v => v.toFixed(3);
  const where = pose.latitude_deg !== null && pose.latitude_deg !== undefined ? `  ${pose.latitude_deg.toFixed(7)}, ${pose.longitude_deg.toFixed(7)}, ${pose.altitude_m.toFixed(1)} m` : "";
  $("pose").textContent = `seq ${pose.seq}  t=${pose.timestamp.toFixed(3)} s  ${pose.state}  quality ${pose.quality}  ` +
    `${pose.metric ? "metric" : "map units"}  t=(${pose.t.map(f).join(", ")})  q(w,x,y,z)=(${pose.q.map(f).join(", ")})${where}`;
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
    option.value = id; option.textContent = `${id} (${state.live[id].device || "mobile"}${state.live[id].ended ? ", " + state.live[id].ended : state.live[id].connected ? "" : ", offline"})`;
    option.selected = id === state.selected;
    select.appendChild(option);
  }
  updateStatusBar();
}

// What a session is doing, honestly: its end and a lost link win over the last status the
// station sent while it was live (which said "starting" or "running").
function sessionState(live) {
  if (!live) return "idle";
  if (live.ended) return live.ended;
  if (!live.connected) return "disconnected (may resume)";
  return live.status ? live.status.state : "starting";
}

function updateStatusBar() {
  const live = state.live[state.selected];
  $("st-comm").textContent = live ? (live.connected ? "connected" : "disconnected") : "no mobile station";
  const s = live && live.status, streaming = live && live.connected && !live.ended;
  $("st-state").textContent = sessionState(live);
  $("st-fps").textContent = s && streaming ? s.fps.toFixed(1) : "0";
  $("st-latency").textContent = s && streaming && s.latency_ms_p50 ? s.latency_ms_p50.toFixed(0) + " ms" : "–";
  $("st-frames").textContent = s ? `${s.frames_received} received, ${s.frames_estimated} estimated` : "0";
  $("st-dropped").textContent = s ? String(s.frames_dropped) : "0";
  const mission = $("mission-link");  // a vehicle in autopilot.vehicles: its marker mission's page
  mission.hidden = !(live && live.mission);
  if (live && live.mission) mission.href = `/mission?session=${encodeURIComponent(state.selected)}`;
}

// The recorded sessions' rows follow the live counts between reloads (the table is read from the
// database on connect and end; the status bar's counts come every second): both show one number.
function updateSessionRow(id) {
  const live = state.live[id], row = document.querySelector(`#sessions tbody tr[data-session="${id}"]`);
  if (!live || !row || !live.status) return;
  const s = live.status;
  row.cells[2].textContent = live.ended || (live.connected ? "live" : "disconnected");
  row.cells[3].textContent = s.frames_received; row.cells[4].textContent = s.frames_estimated; row.cells[5].textContent = s.frames_dropped;
}

// the station's orthophoto, drawn under georeferenced top views once it has loaded
function loadBackground(background) {
  if (!background || (state.background && state.background.url === background.url)) return;
  const image = new Image();
  image.onload = () => { state.background = { ...background, image }; scheduleRedraw(); };
  image.src = background.url;
}

function fillSettings(config) {
  state.config = config;
  for (const [key, value] of Object.entries(config.orb || {})) $("orb-form").elements[key].value = value;
  const form = $("camera-form").elements;
  for (const [key, value] of Object.entries(config.camera || {})) if (form[key]) form[key].value = value;
  form.fps.value = config.fps; form.color_space.value = config.color_space;
}

async function loadSessions() {
  const response = await fetch("/api/sessions");
  if (!response.ok) return;
  const body = await response.json();
  const tbody = document.querySelector("#sessions tbody");
  tbody.innerHTML = "";
  for (const s of body.sessions) {
    const row = tbody.insertRow();
    row.dataset.session = s.id;
    for (const value of [s.id, s.device, s.status, s.frames_received, s.frames_estimated, s.frames_dropped]) row.insertCell().textContent = value;
    row.insertCell().innerHTML = `<a href="/api/sessions/${encodeURIComponent(s.id)}/trajectory.tum">TUM</a> · <a href="/api/sessions/${encodeURIComponent(s.id)}/recording.mcap">MCAP</a>`;
    updateSessionRow(s.id);
  }
}

function onMessage(message) {
  switch (message.type) {
    case "snapshot": {
      const link = message.link;
      $("phone-url").textContent = $("phone-url").href = link.phone_url || "";
      $("mobile-url").textContent = link.mobile_ws_url || "";
      $("fingerprint").textContent = link.fingerprint_sha256 || "(no TLS)";
      $("access").textContent = link.access || "";
      $("mavlink").textContent = message.mavlink || "off";
      $("data-dir").textContent = message.data_dir; $("db").textContent = message.db;
      fillSettings(message.config);
      loadBackground(message.background);
      state.live = message.live; refreshSelect(); loadSessions();
      break;
    }
    case "pose": {
      series(state.trajectories, message.session_id).push(message.pose);
      if (!state.live[message.session_id]) { state.live[message.session_id] = { connected: true }; refreshSelect(); }
      if (message.session_id === state.selected) { showPose(message.pose); updateBanner(); scheduleRedraw(); }
      break;
    }
    case "gps": series(state.gps, message.session_id).push(message.fix); break;
    case "navigation": state.navigation[message.session_id] = message.navigation; updateBanner(); break;
    case "event": {
      const e = message.event;
      addEvent(e);
      if (ALARMS[e.code]) state.alarms[e.session_id] = ALARMS[e.code];
      if (["gps_back", "trust_restored", "georeferenced"].includes(e.code)) delete state.alarms[e.session_id];
      if (e.session_id === state.selected) updateBanner();
      const live = e.session_id && state.live[e.session_id];
      if (live && ["ended", "interrupted", "released"].includes(e.code)) { live.ended = e.code; live.connected = false; }
      if (live && ["connected", "resumed"].includes(e.code)) { delete live.ended; live.connected = true; }
      if (["connected", "ended", "interrupted", "resumed", "released"].includes(e.code)) loadSessions();
      if (live) { refreshSelect(); }
      break;
    }
    case "status": {
      const live = state.live[message.session_id] = Object.assign(state.live[message.session_id] || {}, { status: message.status, mission: message.mission });
      if (!live.ended) live.connected = message.connected;
      if (!$("session-select").querySelector(`option[value="${message.session_id}"]`)) refreshSelect(); else updateStatusBar();
      if (document.querySelector(`#sessions tbody tr[data-session="${message.session_id}"]`)) updateSessionRow(message.session_id); else loadSessions();
      break;
    }
    case "sessions": loadSessions(); break;
    case "config": fillSettings(message.config); break;
  }
}

function connect() {
  const socket = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws/operator");
  socket.onopen = () => { $("st-link").textContent = "up"; };
  socket.onclose = async () => {
    const status = await fetch("/api/state").then(r => r.status, () => 0);
    $("st-link").textContent = status === 401 ? "not logged in: open the login link evp serve printed (or evp pairing-code --role operator)" : "down (retrying)";
    setTimeout(connect, status === 401 ? 5000 : 1000);
  };
  socket.onmessage = event => onMessage(JSON.parse(event.data));
}

// The login: the link evp serve prints carries a one-time code in its fragment (never sent to a
// server); traded once, it leaves an HttpOnly cookie this page never sees.
async function logInIfAsked() {
  const code = new URLSearchParams(location.hash.slice(1)).get("pair");
  if (!code) return;
  history.replaceState(null, "", location.pathname);
  const response = await fetch("/api/pair", { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify({ code, device: "operator page" }) });
  if (!response.ok) $("st-link").textContent = "login refused: " + (await response.json()).error;
}

const postJson = (url, body) => fetch(url, { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body || {}) });

// A phone pairs by scanning a one-time QR code (the phone page's address, the code in its fragment).
async function pairPhone() {
  const response = await postJson("/api/pairing", { role: "mobile" });
  const body = await response.json();
  if (!response.ok) { $("pairing").textContent = "refused: " + body.error; return; }
  $("qr").src = "data:image/svg+xml;charset=utf-8," + encodeURIComponent(body.qr_svg);
  $("qr").hidden = false;
  $("pairing").textContent = `one use, valid ${Math.round(body.expires_in_s / 60)} min: ${body.url}`;
  state.pairingUrl = body.url;
}

async function command(action) {
  if (!state.selected) return;
  const response = await postJson(`/api/sessions/${encodeURIComponent(state.selected)}/${action}`);
  if (!response.ok) addEvent({ t: Date.now() / 1000, level: "error", code: action, text: (await response.json()).error, session_id: state.selected });
  if (action === "start") state.trajectories[state.selected] = new DecimatedSeries();
}

async function configure() {
  const orb = {}, camera = {};
  for (const input of $("orb-form").elements) orb[input.name] = Number(input.value);
  const form = $("camera-form").elements;
  for (const key of ["width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]) camera[key] = Number(form[key].value);
  const body = { orb, camera, fps: Number(form.fps.value), color_space: form.color_space.value };
  const response = await postJson("/api/configure", body);
  const result = await response.json();
  $("configure-result").textContent = response.ok ? "stored and sent to the mobile stations" : "refused: " + result.error;
}

$("pair-phone").onclick = pairPhone;
$("camera-button").onclick = () => $("camera-dialog").showModal();
$("configure").onclick = configure;
$("start").onclick = () => command("start");
$("stop").onclick = () => command("stop");
$("resume").onclick = () => command("resume");
$("plane").onchange = redraw;
$("session-select").onchange = event => { state.selected = event.target.value; updateStatusBar(); updateBanner(); redraw(); };
redraw();
logInIfAsked().finally(connect);
