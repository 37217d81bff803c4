// Canvas charts: the gray histogram and the threshold sweep (threshold calibration), the
// per-photo reprojection errors of a camera calibration, and a flight's camera position and
// tracking state over time.

import { settingText } from "./settings.js";

const PAD = { left: 34, right: 34, top: 10, bottom: 20 };
const INK = "#57606a";
const GRID = "#d8dee4";
const FONT = "10px system-ui, sans-serif";
const COLORS = {
  threshold: "#0969da", suggested: "#1a7f37", white: "#57606a", background: "#9a6700", high: "#bc4c00",
  bars: "#8c959f", correct: "#1a7f37", margin: "#8250df", band: "rgba(26,127,55,0.12)",
  outlier: "#cf222e", excluded: "#d0d7de", selected: "#0969da",
  x: "#cf222e", y: "#1a7f37", z: "#0969da", detected: "#8250df", tracked: "#1a7f37", unseen: "#eaeef2",
};

/** Size the canvas for the device's pixel ratio and return plot-area transforms for x in [x0, x1];
 *  `digits`: label five values along x with at most that many decimals (0: whole numbers, each
 *  once); null for charts that label their own categories. */
function plot(canvas, x0, x1, digits = 2) {
  const ratio = window.devicePixelRatio || 1;
  const width = canvas.clientWidth, height = canvas.clientHeight;
  canvas.width = Math.round(width * ratio);
  canvas.height = Math.round(height * ratio);
  const ctx = canvas.getContext("2d");
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  ctx.clearRect(0, 0, width, height);
  ctx.font = FONT;
  const w = width - PAD.left - PAD.right, h = height - PAD.top - PAD.bottom;
  const x = (v) => PAD.left + ((v - x0) / (x1 - x0)) * w;
  const y = (f) => PAD.top + h - f * h;   // f: fraction of the plot height
  ctx.strokeStyle = GRID;
  ctx.strokeRect(PAD.left + 0.5, PAD.top + 0.5, w, h);
  ctx.fillStyle = INK;
  ctx.textAlign = "center";
  ctx.textBaseline = "top";
  const ticks = digits === null ? [] : [0, 1, 2, 3, 4].map((i) => Number((x0 + ((x1 - x0) * i) / 4).toFixed(digits)));
  axisLabels(ctx, [...new Set(ticks)].map((v) => [x(v), String(v)]), width, PAD.top + h + 4);
  return { ctx, x, y, w, h };
}

/** `labels` ([x, text], left to right) under the x axis at `top`, each centred on its x but kept
 *  inside the canvas's `width`. One that would touch the label before it is left out, except the
 *  last (the axis' end), which replaces the one before: the seed's 0 … 2147483647 overlapped. */
function axisLabels(ctx, labels, width, top) {
  const GAP = 6;
  const boxes = labels.map(([x, text]) => {
    const w = ctx.measureText(text).width;
    const left = Math.min(Math.max(x - w / 2, 0), width - w);
    return { text, left, right: left + w };
  });
  const kept = [];
  boxes.forEach((box, i) => {
    const last = i === boxes.length - 1;
    while (kept.length && kept[kept.length - 1].right + GAP > box.left) {
      if (!last || kept.length === 1) return;
      kept.pop();
    }
    kept.push(box);
  });
  ctx.save();
  ctx.textAlign = "left";
  for (const { text, left } of kept) ctx.fillText(text, left, top);
  ctx.restore();
}

function marker(p, value, color, label, dash = [], row = 0) {
  if (value === null || value === undefined) return;
  const { ctx, x, y } = p;
  ctx.save();
  ctx.strokeStyle = color;
  ctx.setLineDash(dash);
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  ctx.moveTo(Math.round(x(value)) + 0.5, y(0));
  ctx.lineTo(Math.round(x(value)) + 0.5, y(1));
  ctx.stroke();
  ctx.fillStyle = color;
  ctx.textBaseline = "top";
  ctx.textAlign = x(value) > PAD.left + p.w * 0.65 ? "right" : "left";
  if (label) ctx.fillText(` ${label} `, x(value), y(1) + 2 + row * 12);
  ctx.restore();
}

/** Canvas x (client px) -> data value, for click-to-set on a chart drawn over [x0, x1]. */
export function valueAt(canvas, clientX, x0, x1) {
  const left = canvas.getBoundingClientRect().left + PAD.left;
  const w = canvas.clientWidth - PAD.left - PAD.right;
  return Math.min(x1, Math.max(x0, x0 + ((clientX - left) / w) * (x1 - x0)));
}

/** 256-bin histogram of the normalised gray in the calibration region, log counts so that both the
 *  sign's white and its dark text show. */
export function drawHistogram(canvas, calib, settings) {
  const p = plot(canvas, 0, 1);
  const { ctx, x, y } = p;
  const hist = calib.histogram;
  const top = Math.log1p(Math.max(...hist, 1));
  const binW = x(1 / hist.length) - x(0);
  hist.forEach((count, i) => {
    const v = i / hist.length;
    ctx.fillStyle = v >= settings.threshold && (settings.high_threshold ?? 1) >= v ? "#a8c7fa" : COLORS.bars;
    const f = Math.log1p(count) / top;
    ctx.fillRect(x(v), y(f), Math.max(1, binW), y(0) - y(f));
  });
  ctx.fillStyle = INK;
  ctx.save();
  ctx.translate(10, p.y(0.5));
  ctx.rotate(-Math.PI / 2);
  ctx.textAlign = "center";
  ctx.fillText("log count", 0, 0);
  ctx.restore();
  // Only the settings are labelled on the chart; the measured levels are named in the legend below.
  marker(p, calib.background_level, COLORS.background, "", [1, 2]);
  marker(p, calib.white_level, COLORS.white, "", [2, 3]);
  marker(p, calib.suggested_threshold, COLORS.suggested, "", [5, 3]);
  if (settings.high_threshold !== null) {
    marker(p, settings.high_threshold, COLORS.high, `high ${settingText("high_threshold", settings.high_threshold)}`,
      [], 1);
  }
  marker(p, settings.threshold, COLORS.threshold, `threshold ${settingText("threshold", settings.threshold)}`);
}

function series(p, xs, ys, max, color) {
  const { ctx, x, y } = p;
  ctx.strokeStyle = color;
  ctx.fillStyle = color;
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  xs.forEach((v, i) => (i ? ctx.lineTo(x(v), y(ys[i] / max)) : ctx.moveTo(x(v), y(ys[i] / max))));
  ctx.stroke();
  xs.forEach((v, i) => ctx.fillRect(x(v) - 2, y(ys[i] / max) - 2, 4, 4));
}

/** Correct count (left axis) and smallest margin (right axis) against the swept setting's value,
 *  labelled with `digits` decimals (0 for an integer setting); its `current` value as the form shows it. */
export function drawSweep(canvas, sweep, current, digits) {
  const xs = sweep.values;
  const p = plot(canvas, xs[0], xs[xs.length - 1], digits);
  const { ctx, x, y, w } = p;
  if (sweep.band) {
    ctx.fillStyle = COLORS.band;
    ctx.fillRect(x(sweep.band[0]), y(1), x(sweep.band[1]) - x(sweep.band[0]), y(0) - y(1));
  }
  const labelled = Math.max(sweep.labelled, 1);
  const margins = sweep.min_margin.map((m) => m ?? 0);
  const maxMargin = Math.max(...margins, 1);
  series(p, xs, margins.map((m) => Math.max(m, 0)), maxMargin, COLORS.margin);
  series(p, xs, sweep.correct, labelled, COLORS.correct);
  ctx.textBaseline = "middle";
  ctx.textAlign = "right";
  ctx.fillStyle = COLORS.correct;
  ctx.fillText(String(sweep.labelled), PAD.left - 4, y(1));
  ctx.fillText("0", PAD.left - 4, y(0));
  ctx.textAlign = "left";
  ctx.fillStyle = COLORS.margin;
  ctx.fillText(String(maxMargin), PAD.left + w + 4, y(1));
  ctx.fillText("0", PAD.left + w + 4, y(0));
  marker(p, sweep.centre, COLORS.suggested, `centre ${(sweep.centre ?? 0).toFixed(digits)}`, [5, 3], 1);
  if (current >= xs[0] && current <= xs[xs.length - 1]) {
    marker(p, current, COLORS.threshold, `now ${settingText(sweep.param, current)}`);
  }
}

function level(p, f, color, label, dash = []) {
  const { ctx, y, w } = p;
  ctx.save();
  ctx.strokeStyle = color;
  ctx.fillStyle = color;
  ctx.setLineDash(dash);
  ctx.beginPath();
  ctx.moveTo(PAD.left, Math.round(y(f)) + 0.5);
  ctx.lineTo(PAD.left + w, Math.round(y(f)) + 0.5);
  ctx.stroke();
  ctx.textAlign = "left";
  ctx.textBaseline = "middle";
  ctx.fillText(label, PAD.left + w + 3, y(f));
  ctx.restore();
}

/** One bar per calibration photo: its RMS reprojection error (px) under the fitted camera. Outliers
 *  are red, photos left out of the fit pale, photos without a board an empty slot; the dashed
 *  line is the outlier threshold, the solid one the overall RMS. `selected`: index to outline. */
export function drawViewErrors(canvas, views, result, selected) {
  const n = Math.max(views.length, 1);
  const p = plot(canvas, 0, n, null);
  const { ctx, x, y } = p;
  const errors = views.map((v) => v.error_px ?? 0);
  const top = Math.max(...errors, result.outlier_threshold_px, result.rms_px) * 1.1;
  const barW = x(1) - x(0);
  views.forEach((v, i) => {
    const f = (v.error_px ?? 0) / top;
    ctx.fillStyle = v.excluded ? COLORS.excluded : v.outlier ? COLORS.outlier : COLORS.bars;
    ctx.fillRect(x(i + 0.15), y(f), barW * 0.7, y(0) - y(f));
    if (i === selected) {
      ctx.strokeStyle = COLORS.selected;
      ctx.lineWidth = 2;
      ctx.strokeRect(x(i + 0.08), y(1), barW * 0.84, y(0) - y(1));
    }
    ctx.fillStyle = INK;
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    if (barW >= 12 || i % Math.ceil(12 / barW) === 0) ctx.fillText(String(i + 1), x(i + 0.5), y(0) + 4);
    if (!v.found) ctx.fillText("–", x(i + 0.5), y(0) - 12);
  });
  ctx.textAlign = "right";
  ctx.textBaseline = "middle";
  ctx.fillText(top.toFixed(2), PAD.left - 4, y(1));
  ctx.fillText("0", PAD.left - 4, y(0));
  level(p, result.outlier_threshold_px / top, COLORS.outlier, "outlier", [4, 3]);
  level(p, result.rms_px / top, COLORS.suggested, "RMS");
}

/** Index of the bar under a click at `clientX` on a chart of `n` bars drawn by drawViewErrors. */
export function barAt(canvas, clientX, n) {
  return Math.min(n - 1, Math.floor(valueAt(canvas, clientX, 0, n)));
}

/** A flight's camera position in the sign's frame (m) against time (s): `times` and `positions`
 *  ([x, y, z] or null where the sign was not seen, which breaks the lines), over [t0, t1]; the frame
 *  shown at `cursor` s. */
export function drawFlightPositions(canvas, times, positions, t0, t1, cursor) {
  const p = plot(canvas, t0, Math.max(t1, t0 + 1e-3), 1);
  const { ctx, x, y, w } = p;
  const values = positions.filter(Boolean).flat();
  const lo = Math.min(...values, 0), hi = Math.max(...values, 0);
  const span = hi - lo || 1;
  const f = (v) => (v - lo) / span;
  ["x", "y", "z"].forEach((axis, k) => {
    ctx.strokeStyle = COLORS[axis];
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    let drawing = false;
    positions.forEach((position, i) => {
      if (!position) { drawing = false; return; }
      if (drawing) ctx.lineTo(x(times[i]), y(f(position[k])));
      else ctx.moveTo(x(times[i]), y(f(position[k])));
      drawing = true;
    });
    ctx.stroke();
    ctx.fillStyle = COLORS[axis];
    ctx.textAlign = "left";
    ctx.textBaseline = "top";
    ctx.fillText(axis, PAD.left + w + 4 + 10 * k, PAD.top);
  });
  ctx.fillStyle = INK;
  ctx.textAlign = "right";
  ctx.textBaseline = "middle";
  ctx.fillText(`${hi.toFixed(1)} m`, PAD.left - 2, y(1));
  ctx.fillText(lo.toFixed(1), PAD.left - 2, y(0));
  if (lo < 0 && hi > 0) ctx.fillText("0", PAD.left - 2, y(f(0)));
  marker(p, cursor, COLORS.selected, "");
}

/** A flight's state per frame, a bar each: "detected", "tracked" or null (the sign not seen), over
 *  [t0, t1] s at `times`; the frame shown at `cursor` s. */
export function drawFlightStates(canvas, times, states, t0, t1, cursor) {
  const p = plot(canvas, t0, Math.max(t1, t0 + 1e-3), 1);
  const { ctx, x, y } = p;
  const step = times.length > 1 ? (t1 - t0) / (times.length - 1) : 1;
  states.forEach((state, i) => {
    ctx.fillStyle = COLORS[state ?? "unseen"];
    ctx.fillRect(x(times[i] - step / 2), y(0.9), Math.max(1, x(times[i] + step / 2) - x(times[i] - step / 2)),
      y(0.1) - y(0.9));
  });
  marker(p, cursor, COLORS.selected, "");
}
