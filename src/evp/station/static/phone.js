// Mobile station in the browser: camera (getUserMedia), IMU (DeviceMotion), GPS (Geolocation)
// streamed to the station with protocol v1 (docs/protocol.md); shows the pose that comes back.
"use strict";

const $ = id => document.getElementById(id);
const PROTOCOL = 1, ENCODING = { jpeg: 1, png: 2 };
const phone = { socket: null, config: null, sessionId: null, nextSeq: 0, sent: 0, poses: 0, dropped: 0, errors: 0, skipped: 0, imu: 0, imuRows: [], gps: 0,
                stream: null, timer: null, sending: Promise.resolve(), inFlight: 0 };
// frames captured but not yet sent (being encoded): beyond this the phone is behind, and a new
// frame is skipped at capture rather than queued (the station wants the newest frame anyway)
const MAX_IN_FLIGHT = 2;
window.evpPhone = phone;

function log(text) {
  const line = document.createElement("div");
  line.textContent = new Date().toLocaleTimeString() + " " + text;
  $("log").prepend(line);
}

function send(message) {
  if (phone.socket && phone.socket.readyState === WebSocket.OPEN) phone.socket.send(JSON.stringify(message));
}

// Pairing: the QR code's address carries a one-time code in its fragment (never sent to a
// server); it is traded once for this phone's own credential, kept in this browser only.
const CREDENTIAL = "evp.credential";
async function pairIfAsked() {
  const code = new URLSearchParams(location.hash.slice(1)).get("pair");
  if (!code) return;
  history.replaceState(null, "", location.pathname); // the used code leaves the address bar and the history
  const response = await fetch("/api/pair", { method: "POST", headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ code, device: "browser " + navigator.platform }) });
  const body = await response.json();
  if (response.ok) { localStorage.setItem(CREDENTIAL, body.credential); log("paired with the station"); }
  else log("pairing refused: " + body.error + " (ask the operator for a new QR code)");
}

// The station sends a heartbeat every second: a link silent for 3 s is dead (a Wi-Fi handover
// leaves no close frame), so drop it and resume the session on a new one at once.
const DEAD_AFTER_MS = 3000;

// The link opens (and the station starts a session, with its recording) only when the camera
// starts: a phone that opens this page and never streams leaves no empty session behind. The
// station's camera settings come with the link (its config message answers hello).
function configArrived() {
  return phone.config ? Promise.resolve(phone.config) : new Promise(resolve => { phone.onConfig = resolve; });
}

function connect() {
  const socket = phone.socket = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws/mobile");
  socket.binaryType = "arraybuffer";
  phone.heardAt = performance.now();
  socket.onopen = () => {
    $("link").textContent = "up";
    const token = localStorage.getItem(CREDENTIAL) || "";
    send({ type: "hello", protocol: PROTOCOL, token, device: "browser " + navigator.platform, resume: phone.sessionId });
  };
  socket.onclose = () => { if (phone.socket === socket) { $("link").textContent = "down (reconnecting)"; setTimeout(connect, 1000); } };
  socket.onmessage = event => { phone.heardAt = performance.now(); onMessage(JSON.parse(event.data)); };
}

setInterval(() => {
  const socket = phone.socket;
  if (socket && socket.readyState === WebSocket.OPEN && performance.now() - phone.heardAt > DEAD_AFTER_MS) {
    log("link silent for 3 s: reconnecting");
    phone.socket = null; // its close event, whenever it comes, is not ours any more
    socket.close();
    connect();
  }
}, 500);

function onMessage(message) {
  switch (message.type) {
    case "welcome":
      phone.sessionId = message.session_id; phone.nextSeq = message.next_seq; $("session").textContent = message.session_id;
      if (phone.stream && !phone.sensing) { phone.sensing = true; startSensors(); } // once the link is up: the first fix is not lost
      break;
    case "config": phone.config = message; if (phone.onConfig) { phone.onConfig(message); phone.onConfig = null; } log(`config: ${message.camera.width}x${message.camera.height} at ${message.fps} fps, ${message.encoding}`); if (phone.stream) announce(); break;
    case "pose": phone.poses++; showPose(message); break;
    case "dropped": phone.dropped++; break;
    case "enable": $("enable").checked = message.enabled; break;
    case "status": break;
    case "error":
      phone.errors++;
      log(`station error ${message.code}: ${message.message}`);
      if (message.code === "bad_token") log("this phone is not paired with the station: scan the QR code on the operator page");
      break;
  }
  $("poses").textContent = phone.poses; $("dropped").textContent = phone.dropped;
}

function showPose(p) {
  const f = v => v.toFixed(3);
  $("pose").textContent = `${p.state} t=(${p.t.map(f).join(", ")}) q=(${p.q.map(f).join(", ")}) quality ${p.quality}`;
}

// What this phone streams: the station's camera, at the station's resolution (the video is
// scaled to it, so the station's intrinsics stay valid when the aspect ratio matches).
function announce() {
  const c = phone.config;
  const track = phone.stream.getVideoTracks()[0].getSettings();
  if (Math.abs(track.width / track.height - c.camera.width / c.camera.height) > 0.01)
    log(`camera gives ${track.width}x${track.height}: stretched to ${c.camera.width}x${c.camera.height}, calibrate at that aspect`);
  send({ type: "config", camera: c.camera, fps: c.fps, encoding: c.encoding === "png" ? "png" : "jpeg", color_space: "bgr",
         T_body_cam: cameraExtrinsic(), answers: "at_once" });
  clearInterval(phone.timer);
  phone.timer = setInterval(captureFrame, 1000 / c.fps);
}

function header(seq, timestamp, encoding, width, height, length) {
  const view = new DataView(new ArrayBuffer(32));
  [69, 86, 80, 73].forEach((b, i) => view.setUint8(i, b)); // "EVPI"
  view.setUint8(4, PROTOCOL); view.setUint8(5, ENCODING[encoding]); view.setUint16(6, 0, true);
  view.setUint32(8, seq, true); view.setUint16(12, width, true); view.setUint16(14, height, true);
  view.setFloat64(16, timestamp, true); view.setUint32(24, length, true);
  return view.buffer;
}

// A frame's sequence number and timestamp are taken together, when it is captured, and frames
// are sent in capture order: encoding (toBlob) is asynchronous, and a loaded phone finishes two
// encodings out of order, which the station refuses as out of order (docs/protocol.md).
function captureFrame() {
  const c = phone.config, video = $("preview"), canvas = $("frame");
  if (!c || video.readyState < 2 || !phone.socket || phone.socket.readyState !== WebSocket.OPEN) return;
  if (phone.socket.bufferedAmount > 1 << 20 || phone.inFlight >= MAX_IN_FLIGHT) { $("skipped").textContent = ++phone.skipped; return; } // behind: skip rather than queue
  canvas.width = c.camera.width; canvas.height = c.camera.height;
  canvas.getContext("2d").drawImage(video, 0, 0, canvas.width, canvas.height);
  const seq = phone.nextSeq++, timestamp = performance.now() / 1000, encoding = c.encoding === "png" ? "png" : "jpeg";
  const { width, height } = canvas;
  const encoded = new Promise(resolve => canvas.toBlob(resolve, "image/" + encoding, (c.jpeg_quality || 85) / 100)).then(blob => blob.arrayBuffer());
  phone.inFlight++;
  phone.sending = phone.sending.then(() => encoded).then(payload => {
    const frame = new Uint8Array(32 + payload.byteLength);
    frame.set(new Uint8Array(header(seq, timestamp, encoding, width, height, payload.byteLength)), 0);
    frame.set(new Uint8Array(payload), 32);
    flushImu(); // the IMU up to the frame arrives before it
    if (phone.socket.readyState === WebSocket.OPEN) { phone.socket.send(frame.buffer); phone.sent++; $("sent").textContent = phone.sent; }
  }).catch(error => log("frame " + seq + ": " + error)).finally(() => { phone.inFlight--; });
}

// The back camera in the phone's IMU axes (W3C device axes: x right, y to the top of the screen,
// z out of the screen; the camera looks along -z), for the screen's orientation (the image's
// right and down edges turn with it). The lenses sit a few cm from the IMU: taken as 0.
function cameraExtrinsic() {
  const angle = (screen.orientation && screen.orientation.angle) || 0;
  const [right, down] = { 90: [[0, -1, 0], [-1, 0, 0]], 180: [[-1, 0, 0], [0, 1, 0]], 270: [[0, 1, 0], [1, 0, 0]] }[angle] || [[1, 0, 0], [0, -1, 0]];
  const forward = [0, 0, -1];
  return [0, 1, 2].flatMap(i => [right[i], down[i], forward[i], 0]).concat([0, 0, 0, 1]);
}

// IMU samples go together (kind imu_batch): before each frame, and at most IMU_BATCH_SPAN_S of them
// without frames; a message a sample costs the station more than the frames (docs/protocol.md).
const IMU_BATCH_SPAN_S = 0.05;
function flushImu() {
  const rows = phone.imuRows;
  if (!rows.length) return;
  phone.imuRows = [];
  send({ type: "telemetry", kind: "imu_batch", timestamp: rows.at(-1)[0], samples: rows });
}

function startSensors() {
  const deg = Math.PI / 180;
  window.addEventListener("devicemotion", e => {
    const r = e.rotationRate, a = e.accelerationIncludingGravity;
    if (!r || !a || r.alpha === null || a.x === null) return;
    // W3C: rotationRate in deg/s about the device z (alpha), x (beta), y (gamma) axes
    phone.imuRows.push([performance.now() / 1000, r.beta * deg, r.gamma * deg, r.alpha * deg, a.x, a.y, a.z]);
    if (phone.imuRows.at(-1)[0] - phone.imuRows[0][0] >= IMU_BATCH_SPAN_S || phone.imuRows.length >= 256) flushImu();
    $("imu").textContent = ++phone.imu;
  });
  if (navigator.geolocation) navigator.geolocation.watchPosition(p => {
    const c = p.coords;
    send({ type: "telemetry", kind: "gps", timestamp: performance.now() / 1000, latitude_deg: c.latitude, longitude_deg: c.longitude,
      altitude_m: c.altitude ?? 0, horizontal_accuracy_m: c.accuracy ?? undefined, vertical_accuracy_m: c.altitudeAccuracy ?? undefined });
    $("gps").textContent = ++phone.gps;
  }, error => log("GPS: " + error.message), { enableHighAccuracy: true });
}

async function start() {
  if (typeof DeviceMotionEvent !== "undefined" && DeviceMotionEvent.requestPermission) {
    try { await DeviceMotionEvent.requestPermission(); } catch (error) { log("motion sensors: " + error); } // iOS asks on a tap
  }
  $("start").disabled = true;
  connect(); // the station answers hello with its config; the frames start with the camera (announce)
  const c = await configArrived();
  try {
    phone.stream = await navigator.mediaDevices.getUserMedia({ audio: false, video: {
      facingMode: "environment", width: { ideal: c.camera.width }, height: { ideal: c.camera.height }, frameRate: { ideal: c.fps } } });
  } catch (error) { log("camera: " + error); return; }
  $("preview").srcObject = phone.stream;
  announce();
  if (!phone.sensing) { phone.sensing = true; startSensors(); } // the link is up: the first fix is not lost
}

$("start").onclick = start;
$("enable").onchange = event => send({ type: "enable", enabled: event.target.checked });
pairIfAsked().then(() => { $("link").textContent = "ready (opens when the camera starts)"; });
