// Canvas plots with real axes, drawn here because the station runs offline (no charting library
// from a CDN): ticks at round numbers (1, 2, 5 x 10^k), grid lines, labels with units, and on a
// top view (equal axes) a scale bar. Also a decimated series for long sessions.
"use strict";

const PLOT = { left: 56, right: 12, top: 12, bottom: 40 };

function niceRange(values, pad) {
  let lo = Math.min(...values), hi = Math.max(...values);
  if (!isFinite(lo)) { lo = -1; hi = 1; }
  if (hi - lo < 1e-6) { lo -= 0.5; hi += 0.5; }
  const margin = (hi - lo) * pad;
  return [lo - margin, hi + margin];
}

// the round step (1, 2 or 5 x 10^k) that puts about `count` ticks across `span`
function niceStep(span, count) {
  const raw = span / Math.max(1, count), power = Math.pow(10, Math.floor(Math.log10(raw)));
  const unit = raw / power;
  return (unit < 1.5 ? 1 : unit < 3.5 ? 2 : unit < 7.5 ? 5 : 10) * power;
}

function ticks(range, count) {
  const step = niceStep(range[1] - range[0], count), out = [];
  for (let v = Math.ceil(range[0] / step) * step; v <= range[1] + step * 1e-9; v += step) out.push(Math.abs(v) < step * 1e-9 ? 0 : v);
  return { values: out, step };
}

function tickLabel(value, step) {
  const decimals = Math.max(0, -Math.floor(Math.log10(step) + 1e-9));
  return value.toFixed(Math.min(decimals, 6));
}

function drawAxes(ctx, w, h, xr, yr, labels) {
  const pw = w - PLOT.left - PLOT.right, ph = h - PLOT.top - PLOT.bottom;
  const px = x => PLOT.left + (x - xr[0]) / (xr[1] - xr[0]) * pw, py = y => PLOT.top + ph - (y - yr[0]) / (yr[1] - yr[0]) * ph;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  ctx.font = "11px sans-serif"; ctx.lineWidth = 1;
  const xt = ticks(xr, Math.max(3, Math.floor(pw / 70))), yt = ticks(yr, Math.max(3, Math.floor(ph / 40)));
  ctx.strokeStyle = "#e4e4e4"; ctx.fillStyle = "#333";
  ctx.textAlign = "center"; ctx.textBaseline = "top";
  for (const v of xt.values) {
    const x = Math.round(px(v)) + 0.5;
    ctx.beginPath(); ctx.moveTo(x, PLOT.top); ctx.lineTo(x, PLOT.top + ph); ctx.stroke();
    ctx.fillText(tickLabel(v, xt.step), x, PLOT.top + ph + 4);
  }
  ctx.textAlign = "right"; ctx.textBaseline = "middle";
  for (const v of yt.values) {
    const y = Math.round(py(v)) + 0.5;
    ctx.beginPath(); ctx.moveTo(PLOT.left, y); ctx.lineTo(PLOT.left + pw, y); ctx.stroke();
    ctx.fillText(tickLabel(v, yt.step), PLOT.left - 4, y);
  }
  ctx.strokeStyle = "#888"; ctx.strokeRect(PLOT.left + 0.5, PLOT.top + 0.5, pw, ph);
  ctx.textAlign = "center"; ctx.textBaseline = "bottom"; ctx.fillText(labels[0], PLOT.left + pw / 2, h - 2);
  ctx.save(); ctx.translate(12, PLOT.top + ph / 2); ctx.rotate(-Math.PI / 2); ctx.textBaseline = "middle"; ctx.fillText(labels[1], 0, 0); ctx.restore();
  ctx.textAlign = "left"; ctx.textBaseline = "alphabetic";
  return { px, py, pw, ph, xticks: xt.values, yticks: yt.values };
}

// A bar of a round length (about a fifth of the plot's width) at the bottom left, labelled in
// `unit`: how far things are on a top view without reading the ticks.
function drawScaleBar(ctx, frame, xr, unit) {
  const length = niceStep((xr[1] - xr[0]) / 5, 1), pixels = length / (xr[1] - xr[0]) * frame.pw;
  const x0 = PLOT.left + 12, y0 = PLOT.top + frame.ph - 12;
  ctx.strokeStyle = "#000"; ctx.lineWidth = 2; ctx.beginPath();
  ctx.moveTo(x0, y0 - 4); ctx.lineTo(x0, y0); ctx.lineTo(x0 + pixels, y0); ctx.lineTo(x0 + pixels, y0 - 4); ctx.stroke();
  ctx.lineWidth = 1; ctx.fillStyle = "#000"; ctx.fillText(`${tickLabel(length, length)} ${unit}`, x0 + pixels + 6, y0);
  return length;
}

// An image under the plot (an orthophoto under a top view): `background.image` (loaded) spans
// the plot coordinates from `background.corners[0]` (its lower left) to `corners[1]` (its upper
// right), clipped to the plot's frame and a little faded so the grid and the tracks stay readable.
function drawBackground(ctx, frame, background) {
  const [[x0, y0], [x1, y1]] = background.corners;
  ctx.save();
  ctx.beginPath(); ctx.rect(PLOT.left, PLOT.top, frame.pw, frame.ph); ctx.clip();
  ctx.globalAlpha = 0.8;
  ctx.drawImage(background.image, frame.px(x0), frame.py(y1), frame.px(x1) - frame.px(x0), frame.py(y0) - frame.py(y1));
  ctx.restore();
}

// series: [{points: [[x, y], ...], color, label}, ...]; options.equal: same scale on both axes (a
// top view must not distort the path), with a scale bar in options.unit; options.background: an
// image under it (drawBackground). The last point of the first series is marked (the vehicle
// now). Returns what was drawn (ticks, scale bar, background), for tests.
function plotLines(canvas, series, labels, options = {}) {
  const ctx = canvas.getContext("2d"), w = canvas.width, h = canvas.height;
  const all = series.flatMap(s => s.points);
  let xr = niceRange(all.map(p => p[0]), 0.05), yr = niceRange(all.map(p => p[1]), 0.05);
  const pw = w - PLOT.left - PLOT.right, ph = h - PLOT.top - PLOT.bottom;
  if (options.equal) {
    const scale = Math.max((xr[1] - xr[0]) / pw, (yr[1] - yr[0]) / ph);
    const xc = (xr[0] + xr[1]) / 2, yc = (yr[0] + yr[1]) / 2;
    xr = [xc - scale * pw / 2, xc + scale * pw / 2]; yr = [yc - scale * ph / 2, yc + scale * ph / 2];
  }
  const frame = drawAxes(ctx, w, h, xr, yr, labels);
  if (options.background) drawBackground(ctx, frame, options.background);
  for (const s of series) {
    ctx.strokeStyle = s.color; ctx.lineWidth = 1.5; ctx.beginPath();
    s.points.forEach((p, i) => (i ? ctx.lineTo(frame.px(p[0]), frame.py(p[1])) : ctx.moveTo(frame.px(p[0]), frame.py(p[1]))));
    ctx.stroke();
  }
  const first = series.length ? series[0].points : [];
  if (first.length) {
    const last = first[first.length - 1];
    ctx.fillStyle = "#c62828"; ctx.beginPath(); ctx.arc(frame.px(last[0]), frame.py(last[1]), 4, 0, 2 * Math.PI); ctx.fill();
  }
  series.forEach((s, i) => { if (s.label) { ctx.fillStyle = s.color; ctx.fillText(s.label, w - PLOT.right - 60, PLOT.top + 14 + 14 * i); } });
  const scaleBar = options.equal && all.length ? drawScaleBar(ctx, frame, xr, options.unit || "m") : null;
  canvas.dataset.xticks = frame.xticks.length; canvas.dataset.yticks = frame.yticks.length;
  canvas.dataset.scaleBar = scaleBar === null ? "" : `${scaleBar} ${options.unit || "m"}`;
  canvas.dataset.background = options.background ? "drawn" : "";
  return { xticks: frame.xticks, yticks: frame.yticks, scaleBar, background: Boolean(options.background) };
}

function plotLine(canvas, points, labels, options) { return plotLines(canvas, [{ points, color: "#1565c0" }], labels, options); }

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
