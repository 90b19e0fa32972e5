// Minimal canvas plots (no network access for a charting library): equal-axis XY and time series.
"use strict";

function niceRange(values, pad) {
  let lo = Math.min(...values), hi = Math.max(...values);
  if (!isFinite(lo)) { lo = -1; hi = 1; }
  if (hi - lo < 1e-6) { lo -= 0.5; hi += 0.5; }
  const margin = (hi - lo) * pad;
  return [lo - margin, hi + margin];
}

function drawAxes(ctx, w, h, xr, yr, labels) {
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  ctx.strokeStyle = "#ccc"; ctx.lineWidth = 1; ctx.strokeRect(40.5, 10.5, w - 50, h - 40);
  ctx.fillStyle = "#333"; ctx.font = "11px sans-serif";
  ctx.fillText(xr[0].toFixed(2), 40, h - 16); ctx.fillText(xr[1].toFixed(2), w - 50, h - 16);
  ctx.fillText(yr[1].toFixed(2), 2, 20); ctx.fillText(yr[0].toFixed(2), 2, h - 32);
  ctx.fillText(labels[0], w / 2 - 10, h - 4);
  ctx.save(); ctx.translate(12, h / 2); ctx.rotate(-Math.PI / 2); ctx.fillText(labels[1], 0, 0); ctx.restore();
}

// series: [{points: [[x, y], ...], color}, ...]; equal: same scale on both axes (a top view must
// not distort the path). The last point of the first series is marked (the vehicle now).
function plotLines(canvas, series, labels, equal) {
  const ctx = canvas.getContext("2d"), w = canvas.width, h = canvas.height;
  const all = series.flatMap(s => s.points);
  let xr = niceRange(all.map(p => p[0]), 0.05), yr = niceRange(all.map(p => p[1]), 0.05);
  const pw = w - 50, ph = h - 40;
  if (equal) {
    const scale = Math.max((xr[1] - xr[0]) / pw, (yr[1] - yr[0]) / ph);
    const xc = (xr[0] + xr[1]) / 2, yc = (yr[0] + yr[1]) / 2;
    xr = [xc - scale * pw / 2, xc + scale * pw / 2]; yr = [yc - scale * ph / 2, yc + scale * ph / 2];
  }
  drawAxes(ctx, w, h, xr, yr, labels);
  const px = x => 40 + (x - xr[0]) / (xr[1] - xr[0]) * pw;
  const py = y => 10 + ph - (y - yr[0]) / (yr[1] - yr[0]) * ph;
  for (const s of series) {
    ctx.strokeStyle = s.color; ctx.lineWidth = 1.5; ctx.beginPath();
    s.points.forEach((p, i) => (i ? ctx.lineTo(px(p[0]), py(p[1])) : ctx.moveTo(px(p[0]), py(p[1]))));
    ctx.stroke();
  }
  const first = series.length ? series[0].points : [];
  if (first.length) {
    const last = first[first.length - 1];
    ctx.fillStyle = "#c62828"; ctx.beginPath(); ctx.arc(px(last[0]), py(last[1]), 4, 0, 2 * Math.PI); ctx.fill();
  }
  series.forEach((s, i) => { if (s.label) { ctx.fillStyle = s.color; ctx.fillText(s.label, w - 120, 24 + 14 * i); } });
}

function plotLine(canvas, points, labels, equal) { plotLines(canvas, [{ points, color: "#1565c0" }], labels, equal); }

// A series that stays small however long the session: every point until it holds `max`, then
// every other one is dropped and only every 2nd (4th, ...) new point is kept, so a 2-hour session
// at 30 Hz draws at most `max` points spread over the whole flight; the newest point is always
// kept as `last` (the vehicle now).
class DecimatedSeries {
  constructor(max = 2000) { this.max = max; this.kept = []; this.stride = 1; this.count = 0; this.last = null; }
  push(point) {
    this.last = point;
    if (this.count++ % this.stride) return;
    this.kept.push(point);
    if (this.kept.length > this.max) { this.kept = this.kept.filter((_, i) => i % 2 === 0); this.stride *= 2; }
  }
  get points() { return this.last && this.kept[this.kept.length - 1] !== this.last ? this.kept.concat([this.last]) : this.kept; }
}
