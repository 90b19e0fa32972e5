// The live marker mission: polls its state, draws the map and the camera, posts commands.
// On evp serve (/mission?session=ID) the mission is that session's vehicle; on evp fly --serve
// (/) it is the simulated one.
"use strict";

const $ = (id) => document.getElementById(id);
const session = new URLSearchParams(location.search).get("session");
const api = session ? `/api/sessions/${encodeURIComponent(session)}/mission` : "/api/mission";

async function send(kind, markerId) {
  const body = { kind };
  if (markerId !== undefined) body.marker_id = markerId;
  const response = await fetch(`${api}/command`, { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
  const answer = await response.json();
  $("command-result").textContent = `${kind}${markerId !== undefined ? " " + markerId : ""}: ${answer.accepted ? "accepted" : "refused"} ${answer.detail || answer.error || ""}`;
}

function draw(state) {
  const canvas = $("map");
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const points = state.markers.map((m) => [m.x, m.y]);
  if (state.position) points.push([state.position[0], state.position[1]]);
  if (!points.length) return;
  const xs = points.map((p) => p[0]), ys = points.map((p) => p[1]);
  const lo = [Math.min(...xs) - 0.3, Math.min(...ys) - 0.3], hi = [Math.max(...xs) + 0.3, Math.max(...ys) + 0.3];
  const scale = Math.min(canvas.width / (hi[0] - lo[0]), canvas.height / (hi[1] - lo[1]));
  const px = (x, y) => [(x - lo[0]) * scale, canvas.height - (y - lo[1]) * scale];
  ctx.font = "10px sans-serif";
  for (const m of state.markers) {
    const [u, v] = px(m.x, m.y);
    const half = 0.049 * scale;
    ctx.fillStyle = m.id === state.target ? "#c62828" : "#263238";
    ctx.fillRect(u - half, v - half, 2 * half, 2 * half);
    ctx.fillStyle = "#1565c0";
    ctx.fillText(`${m.id}${m.grid ? ` [${m.grid[0]},${m.grid[1]}]` : ""}`, u - half, v + half + 10);
  }
  if (state.position) {
    const [u, v] = px(state.position[0], state.position[1]);
    const yaw = state.position[2];
    ctx.strokeStyle = "#ef6c00";
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.arc(u, v, 8, 0, 2 * Math.PI);
    ctx.moveTo(u, v);
    ctx.lineTo(u + 16 * Math.cos(yaw), v - 16 * Math.sin(yaw));
    ctx.stroke();
  }
}

async function poll() {
  try {
    const response = await fetch(api);
    if (!response.ok) throw new Error((await response.json()).error);
    const state = await response.json();
    $("clock").textContent = `t = ${state.t.toFixed(1)} s${state.done ? " (mission over)" : ""}`;
    $("state").textContent = state.state;
    const h = state.height_m;
    $("height").textContent = h === null ? "no reading" : `${(h * 1000).toFixed(0)} mm ${h >= state.band_m[0] && h <= state.band_m[1] ? "(in band)" : "(out of band)"}`;
    $("mapped").textContent = state.markers_total === null ? `${state.markers.length}` : `${state.markers.length} of ${state.markers_total}`;
    $("target").textContent = state.target === null ? "none" : state.target;
    $("events").innerHTML = state.events.map((e) => `<div class="event">${e.t.toFixed(2)} ${e.kind}: ${e.detail}</div>`).join("");
    draw(state);
  } catch (error) {
    $("clock").textContent = `mission gone: ${error.message}`;
    return;
  }
  setTimeout(poll, 250);
}

$("goto").onclick = () => send("goto", Number($("marker-id").value));
$("land-on").onclick = () => send("land", Number($("marker-id").value));
$("land").onclick = () => send("land");
$("hold").onclick = () => send("hold");
$("explore").onclick = () => send("explore");
$("abort").onclick = () => send("abort");
poll();
