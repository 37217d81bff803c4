// Detail view of one image: every pipeline stage, the score table, the pose, and the threshold
// calibration tools (box-drag histogram, sweep over all labelled images).

import { api, failureOf, get } from "./api.js";
import { approximateNote, KIND_LABELS } from "./camera.js";
import { drawHistogram, drawSweep, valueAt } from "./charts.js";
import { choose, fillExpected, refreshImages, showStatus } from "./gallery.js";
import { setSetting, settingText, settingValue, stepOf } from "./settings.js";
import { emit, state, on, select, signName } from "./store.js";
import { $, el, fill, fmt, plural, report, toast } from "./ui.js";

let detail = null;          // GET /api/images/{id} of the shown image
let shownKey = "";          // keyOf(shown image): reload only when the result can differ
let loadToken = 0;          // drops responses that arrive after a newer request
let calib = null;           // POST /api/calibrate/threshold answer for the shown image
let calibToken = 0;         // drops measurements of a box or result replaced while they ran
let calibRefused = { key: "", error: "" };  // the last measurement refused (4xx): asked again, it is refused again
let sweep = null;           // GET /api/sweep answer plus the settings it ran under
let sweeping = false;
const boxes = new Map();    // image id -> calibration box [x0, y0, x1, y1] in image px

// The figures are drawn from the result, and a camera or library change re-runs the image under the
// same settings version: the result version changes on every re-run.
const stageUrl = (stage, query = "") => `/api/images/${detail.id}/stages/${stage}?v=${detail.result_version}${query}`;

/** A figure whose <img> shows the server's reason (e.g. "no blob") when the stage cannot be drawn,
 *  or the page's (`none`) when the result already says there is no figure to ask for. */
function stageFigure(title, link = true) {
  const img = el("img", { alt: title, decoding: "async" });
  const note = el("div.stage-note");
  const box = link ? el("a.stage-img", { target: "_blank", title: `${title}: open full size` }, img, note)
    : el("div.stage-img", {}, img, note);
  const caption = el("figcaption", {}, title);
  const fig = el("figure.stage", {}, box, caption);
  img.onload = () => fig.classList.remove("missing");
  img.onerror = async () => {
    const src = img.src;
    const message = await failureOf(src);
    if (img.src !== src) return;
    fig.classList.add("missing");
    note.textContent = message;
  };
  return {
    fig,
    set(url, title) {
      if (title) caption.textContent = title;
      if (link) box.href = url;
      if (img.getAttribute("src") !== url) img.src = url;
    },
    // Not requested: the server would answer 404 or 409, an error in the console for every image.
    none(message, title) {
      if (title) caption.textContent = title;
      if (link) box.removeAttribute("href");
      img.removeAttribute("src");
      fig.classList.add("missing");
      note.textContent = message;
    },
  };
}

const INPUT_TITLE = "input · detected sign outlined · drag a box on the sign to calibrate";
const NOTHING_TO_MEASURE = "No sign or white blob was found to measure: drag a box around the sign, with some "
  + "wall in it, on the input image.";
const input = stageFigure(INPUT_TITLE, false);
const stages = Object.entries({ gray: "normalised gray", mask: "binary mask", blob: "largest blob", crop: "crop" })
  .map(([stage, title]) => ({ stage, figure: stageFigure(title) }));
const TEXT_TITLE = "text check · the photo read through the sign's homography, over the library sign, strip by strip";
const textCheck = stageFigure(TEXT_TITLE);

/** Why the shown image, which has no result, has no figures. */
const noResult = () => (detail.error ? "could not run" : "no result yet");

// ---- rendering

function renderHead() {
  const r = detail.result;
  $("#detail").dataset.id = detail.id;  // which image is shown, for tests and deep links
  $("#detail-name").textContent = detail.name;
  $("#detail-name").title = `${detail.name} · ${detail.width}×${detail.height} px`;
  const badge = $("#detail-badge");
  showStatus(badge, detail.status);
  badge.className = `badge status-${detail.status}`;
  // A failed run has no figures to show: its 0 inliers are no measurement (the reason is in the warnings).
  // A plaque fallback answer has no inliers or margin: its correlation decided.
  const decided = detail.by_plaque ? [`plaque correlation ${detail.plaque_correlation.toFixed(2)}`]
    : [plural(detail.inliers, "inlier"), `margin ${detail.margin ?? "–"}`];
  const outcome = detail.error ? [el("b", {}, "could not run")]
    : [el("b", {}, detail.label ? signName(detail.label) : "no sign"), ...decided];
  const parts = [
    ...outcome,
    r?.timing_ms?.total !== undefined ? `${fmt(r.timing_ms.total, 0)} ms${r.reused_stages?.length ? " (cache)" : ""}` : null,
    `${detail.width}×${detail.height}`,
  ].filter(Boolean);
  fill($("#detail-summary"), ...parts.flatMap((p, i) => (i ? [el("span.sep", {}, "·"), p] : [p])));
  if (document.activeElement !== $("#detail-expected")) fillExpected($("#detail-expected"), detail.expected ?? "");
  const warnings = [detail.error, ...(r?.warnings ?? [])].filter(Boolean);
  fill($("#detail-warnings"), ...warnings.map((w) => el("li", {}, w)));
}

function renderStages() {
  const r = detail.result;
  // A failed run has no figures, but the photo itself still says a lot about why.
  if (r) input.set(stageUrl("input"), INPUT_TITLE);
  else input.set(`/api/images/${detail.id}/file`, `input · the photo as uploaded (${noResult()})`);
  for (const { stage, figure } of stages) {
    if (r) figure.set(stageUrl(stage));
    else figure.none(noResult());
  }
  // The recognised sign's check, else the first winner it turned down: what the figure draws.
  const turnedDown = r?.turned_down?.[0];
  const check = r?.text_check ?? turnedDown?.text_check;
  const bar = detail.settings?.min_text_correlation;
  if (!check) {
    const why = !r ? noResult() : bar > 0
      ? "no sign was recognised and no winner turned down for its text, so no text was checked (the scores say why)"
      : `the text check is off (min_text_correlation ${bar}): set it above 0 to check the recognised sign's text`;
    textCheck.none(why, TEXT_TITLE);
  } else {
    const weakest = check.weakest;
    const whose = r.text_check ? "" : ` · turned down: ${turnedDown.source} read as ${turnedDown.sign}`;
    // Every strip may pass and the winner still be turned down: the plaque holds more words.
    const beyond = check.continued?.length
      ? ` · the plaque and its text go on beyond its ${check.continued.join(" and ")} side` : "";
    const washed = check.washed_out?.length ? ` · ${check.washed_out.length} strip(s) washed out by glare` : "";
    textCheck.set(stageUrl("text"), typeof weakest !== "number" ? `${TEXT_TITLE}${whose}${washed}`
      : `${TEXT_TITLE}${whose} · weakest strip ${weakest.toFixed(3)} (a strip passes at ≥ ${bar})${washed}${beyond}`);
  }
  renderBox();
}

function renderScores() {
  const r = detail.result;
  const scores = r?.scores ?? [];
  const rows = scores.map((s) => el(`tr${s.sign === r.label ? ".winner" : ""}`, {},
    el("td", {}, signName(s.sign)), el("td.num", {}, s.matches), el("td.num", {}, s.inliers),
    el("td.reason", {}, s.sign === r.label ? "winner" : s.reason ?? "runner-up")));
  fill($("#scores"),
    el("thead", {}, el("tr", {}, el("th", {}, "sign"), el("th.num", {}, "matches"), el("th.num", {}, "inliers"),
      el("th", {}, "decision"))),
    el("tbody", {}, rows.length ? rows : el("tr", {}, el("td.reason", { colSpan: 4 }, "no region was searched"))));
  fill($("#attempts"),
    el("thead", {}, el("tr", {}, el("th", {}, "region"), el("th", {}, "box (px)"), el("th", {}, "winner"),
      el("th.num", {}, "margin"))),
    el("tbody", {}, (detail.attempts ?? []).map((a) => el("tr", {},
      el("td", {}, a.source), el("td.mono", {}, a.region ? a.region.join(", ") : "–"),
      el("td", {}, a.winner ? signName(a.winner) : "–"), el("td.num", {}, a.margin ?? "–")))));
  // A re-run takes what the changed setting does not affect from the image's cache: say so, or
  // its times read as what the stages cost.
  const reused = new Set(r?.reused_stages ?? []);
  fill($("#timing"), Object.entries(r?.timing_ms ?? {}).map(([stage, ms]) =>
    el(`span${reused.has(stage) ? ".reused" : ""}`, reused.has(stage) ? { title: "taken from this image's cache" } : {},
      `${stage} `, el("b", {}, `${fmt(ms, 1)}${stage === "total" ? " ms" : ""}`), reused.has(stage) ? " cached" : "")));
}

const kv = (key, value, cls = "") => [el("dt", {}, key), el(`dd${cls}`, {}, value)];

/** Two significant digits: a pose's 1σ spans 0.04 mm to metres. */
const sig = (value) => String(Number(value.toPrecision(2)));

function renderPose() {
  const pose = detail.result?.pose;
  const box = $("#pose");
  if (!pose) {
    const why = detail.error ? "no pose: the image could not be run" : detail.label ? "no pose could be computed"
      : "no sign, so no pose";
    fill(box, el("p.muted", {}, why));
  } else {
    const [x, y, z] = pose.camera_position ?? [];
    const e = pose.euler_deg ?? {};
    const sd = (pose.covariance ?? []).map((row, i) => Math.sqrt(Math.max(row[i] ?? 0, 0)));
    const signed = (v, d) => (v === null || v === undefined ? "–" : `${v >= 0 ? "+" : ""}${v.toFixed(d)}`);
    fill(box, el("dl.pose", {},
      kv("camera x y z", el("span.triple", {}, ...[x, y, z].map((v) => el("span", {}, signed(v, 3))))),
      kv("distance", `${fmt(Math.hypot(x, y, z), 3)} m`),
      kv("yaw pitch roll", el("span.triple", {}, ...[e.yaw, e.pitch, e.roll].map((v) => el("span", {}, `${signed(v, 1)}°`)))),
      kv("reprojection", `${fmt(pose.reprojection_rmse_px, 2)} px RMSE`),
      kv("ambiguous", pose.ambiguous ? "yes: two planar solutions fit almost equally" : "no",
        pose.ambiguous ? ".bad" : ""),
      sd.length === 6 ? kv("1σ rot · t", `${sd.slice(0, 3).map((s) => sig((s * 180) / Math.PI)).join(" ")} ° · `
        + `${sd.slice(3).map((s) => sig(s * 1000)).join(" ")} mm`) : null,
    ), el("p.hint", {}, "metres in the sign frame: origin at the sign centre, x right, y down, z into the wall"));
  }
  renderIntrinsics(detail.camera);
}

/** The intrinsics the pose was computed with, where they came from, and whether that makes it approximate. */
function renderIntrinsics(cam) {
  const box = $("#intrinsics");
  box.dataset.kind = cam?.kind ?? "";
  if (!cam) {
    fill(box, el("p.muted", {}, detail.error ? "none: the image could not be run" : "no result yet"));
    return;
  }
  const note = approximateNote(cam);
  fill(box,
    note ? el("p.warn", {}, note) : null,
    el("dl.pose", {},
      kv("source", el("span", {}, el("b.kind", {}, KIND_LABELS[cam.kind]),
        cam.kind === "typed" ? null : ` · ${cam.source}`), ".plain"),
      kv("fx fy", `${fmt(cam.fx, 1)} ${fmt(cam.fy, 1)} px`),
      kv("cx cy", `${fmt(cam.cx, 1)} ${fmt(cam.cy, 1)} px`),
      kv("distortion", (cam.dist ?? []).every((d) => d === 0) ? "none" : cam.dist.map((d) => fmt(d, 4)).join(" ")),
      kv("size", cam.width ? `${cam.width}×${cam.height}` : "any")));
}

// One row per library sign, kept across renders so unchanged figures are not fetched again.
let matchRows = new Map();   // sign id -> {row, reason, raw, inliers}

function buildMatchRows() {
  matchRows = new Map(state.library.map((sign) => {
    const parts = { reason: el("span.reason"), raw: stageFigure("ratio-test matches"), inliers: stageFigure("RANSAC inliers") };
    parts.row = el("div.match-row", {}, el("div.match-head", {}, el("b", {}, sign.name), parts.reason),
      parts.raw.fig, parts.inliers.fig);
    return [sign.id, parts];
  }));
  fill($("#match-grid"), ...[...matchRows.values()].map((m) => m.row));
}

function renderMatches() {
  const r = detail.result;
  for (const [id, m] of matchRows) {
    const score = r?.scores?.find((s) => s.sign === id);
    const won = r?.label === id;
    m.row.classList.toggle("winner", won);
    m.reason.textContent = won ? "winner" : score?.reason ?? "";
    const query = `&sign=${encodeURIComponent(id)}`;
    const raw = `${score?.matches ?? "–"} ratio-test matches`, inliers = `${score?.inliers ?? "–"} RANSAC inliers`;
    if (score) {
      m.raw.set(stageUrl("matches", query), raw);
      m.inliers.set(stageUrl("inliers", query), inliers);
    } else {
      const why = !r ? noResult() : r.scores.length ? "not scored yet: its re-run is on the way" : "no region was searched";
      m.raw.none(why, raw);
      m.inliers.none(why, inliers);
    }
  }
}

function render() {
  $("#detail").hidden = false;
  $("#detail-empty").hidden = true;
  renderHead();
  renderStages();
  renderScores();
  renderPose();
  renderMatches();
  emit("detail", detail.id);
}

async function load(id) {
  const token = ++loadToken;
  try {
    const body = await get(`/api/images/${encodeURIComponent(id)}`);
    if (token !== loadToken) return;
    // Another image's measurement is not shown under this one while its own is measured.
    if (body.id !== detail?.id) calib = null;
    detail = body;
    shownKey = keyOf(body);
    render();
    renderCalib();
    calibrate();   // the detected sign's region moves with the result
  } catch (err) {
    if (token !== loadToken) return;
    if (err.status !== 404) { report(err); return; }
    // A #image= link to an image removed since, or a card clicked as another tab removed it.
    select(null);
    toast("That image is not on the server (removed, or the link is from another server): pick one in the gallery.",
      "warn");
  }
}

// The label and inliers come with the result version; the expected label is its own (one wrong
// label for another leaves the status as it was).
const keyOf = (img) => `${img.id}:${img.result_version}:${img.status}:${img.expected}`;

function close() {
  // A detail or measurement on its way when the view was closed would otherwise open it again.
  ++loadToken;
  ++calibToken;
  detail = null;
  calib = null;
  shownKey = "";
  $("#detail").hidden = true;
  $("#detail-empty").hidden = false;
}

// ---- threshold calibration

function renderBox() {
  const rect = detail && boxes.get(detail.id);
  const box = $("#drag-rect");
  box.hidden = !rect;
  if (!rect) return;
  const [x0, y0, x1, y1] = rect;
  Object.assign(box.style, {
    left: `${(100 * x0) / detail.width}%`, top: `${(100 * y0) / detail.height}%`,
    width: `${(100 * (x1 - x0)) / detail.width}%`, height: `${(100 * (y1 - y0)) / detail.height}%`,
  });
}

async function calibrate() {
  const id = detail.id;
  const rect = boxes.get(id) ?? null;
  const token = ++calibToken;
  let measured;
  // Without a box the server measures the detected sign, else the blob the answer came from
  // (tuning.sign_region): it would refuse an image with no result, or one with neither.
  // The result version changes with every re-run, so a refusal is not repeated for the same result and box.
  const key = `${id}:${detail.result_version}:${rect}`;
  if (!rect && !detail.result?.corners && !detail.attempts.some((a) => a.source.startsWith("blob "))) {
    measured = { error: NOTHING_TO_MEASURE };
  } else if (calibRefused.key === key) {
    measured = { error: calibRefused.error };
  } else {
    try {
      measured = await api("POST", "/api/calibrate/threshold", { image_id: id, rect });
    } catch (err) {
      // Shown beside the histogram, where the person is looking. Without a box the server refuses
      // (422) an image with no region to measure, in an API user's words.
      measured = { error: !rect && err.status === 422 ? NOTHING_TO_MEASURE : err.message };
      // A busy server (503) or a lost connection may answer the same request next time.
      if (err.status >= 400 && err.status < 500) calibRefused = { key, error: measured.error };
    }
  }
  // A reply to a box since replaced (a second drag, a reload of the result) may come last.
  if (token !== calibToken || detail?.id !== id) return;
  calib = measured;
  renderCalib();
}

function renderCalib() {
  const out = $("#calib-result");
  const typed = $("#calib-box");
  // Results arrive while a box is being typed (a re-run, a settings change): the typing stays.
  if (document.activeElement !== typed || typed.value === typed.dataset.entered) {
    showBox(calib?.rect ?? boxes.get(detail?.id));
  }
  $("#histogram").hidden = !calib?.histogram;
  if (!calib?.histogram) {
    fill(out, calib?.error ? el("span.warn", {}, calib.error) : null);
    return;
  }
  drawHistogram($("#histogram"), calib, state.settings);
  describeChart($("#histogram"), histogramScale());
  const [x0, y0, x1, y1] = calib.rect ?? [];
  const where = boxes.has(detail.id) ? `your box ${x1 - x0}×${y1 - y0} px`
    : `${calib.source} (drag or type a box to measure another region)`;
  const suggestion = calib.suggested_threshold;
  fill(out,
    el("span.calib-where", {}, where),
    el("span", {}, el("i.swatch.white"), "white ", el("b", {}, fmt(calib.white_level))),
    calib.background_level !== null
      ? el("span", {}, el("i.swatch.background"), "surroundings ", el("b", {}, fmt(calib.background_level))) : null,
    el("span", {}, el("i.swatch.suggested"), "suggested ", el("b.suggested", {}, fmt(suggestion))),
    el("button.primary", {
      type: "button", id: "apply-threshold", title: "Set the threshold to the suggested value",
      disabled: Math.abs(suggestion - state.settings.threshold) < 1e-9,
      onclick: () => setSetting("threshold", suggestion),
    }, "apply"),
    calib.warning ? el("span.warn", {}, calib.warning) : null);
}

/** Show `rect` [x0, y0, x1, y1] image px (or none) in the box field, with no problem. */
function showBox(rect) {
  const input = $("#calib-box");
  input.value = input.dataset.entered = rect ? rect.join(", ") : "";
  input.setCustomValidity("");
  $("#calib-box-problem").hidden = true;
}

/** The box typed in `input` ("x0, y0, x1, y1" image px) measured, or what is wrong with it said beside it;
 *  an empty one goes back to the region the pipeline found. The keyboard's way to what a drag does. */
function typeBox(input) {
  const text = input.value.trim();
  const numbers = text.split(/[\s,;]+/).filter(Boolean).map(Number);
  const [x0, y0, x1, y1] = numbers;
  let problem = null;
  if (text && (numbers.length !== 4 || !numbers.every(Number.isInteger))) {
    problem = "type four whole numbers: x0, y0, x1, y1 (image px)";
  } else if (text && !(0 <= x0 && x0 < x1 && x1 <= detail.width && 0 <= y0 && y0 < y1 && y1 <= detail.height)) {
    problem = `a box inside the ${detail.width}×${detail.height} px image, x0 < x1 and y0 < y1`;
  }
  input.setCustomValidity(problem ?? "");
  const said = $("#calib-box-problem");
  said.textContent = problem ?? "";
  said.hidden = !problem;
  if (problem) return;  // kept, with what is wrong with it, until it is mended
  input.dataset.entered = input.value;
  if (text) boxes.set(detail.id, [x0, y0, x1, y1]);
  else boxes.delete(detail.id);
  renderBox();
  calibrate();
}

function bindDrag() {
  const area = $("#drag-area");
  let start = null;
  const toImage = (e) => {
    const r = area.getBoundingClientRect();
    return [Math.min(Math.max(e.clientX - r.left, 0), r.width) * (detail.width / r.width),
      Math.min(Math.max(e.clientY - r.top, 0), r.height) * (detail.height / r.height)];
  };
  const rectFrom = (e) => {
    const [x, y] = toImage(e);
    return [Math.min(start[0], x), Math.min(start[1], y), Math.max(start[0], x), Math.max(start[1], y)].map(Math.round);
  };
  area.addEventListener("pointerdown", (e) => {
    if (!detail || e.button !== 0) return;
    e.preventDefault();
    area.setPointerCapture(e.pointerId);
    start = toImage(e);
  });
  area.addEventListener("pointermove", (e) => {
    if (!start) return;
    boxes.set(detail.id, rectFrom(e));
    renderBox();
  });
  area.addEventListener("pointerup", (e) => {
    if (!start) return;
    const rect = rectFrom(e);
    start = null;
    // A click without a drag goes back to the region the pipeline found.
    if (rect[2] - rect[0] < 4 || rect[3] - rect[1] < 4) boxes.delete(detail.id);
    else boxes.set(detail.id, rect);
    renderBox();
    calibrate();
  });
}

// ---- sweep of one setting over the labelled images

/** The settings a sweep depends on: all but the swept one, so moving that one keeps it current. */
const sweepKey = (settings, param) => JSON.stringify({ ...settings, [param]: null });

/** [lo, hi] widened to whole steps of the setting `entry`, within its bounds. */
function onSteps([lo, hi], entry) {
  const step = stepOf(entry), tidy = (x) => Number(x.toPrecision(10));
  return [Math.max(entry.min, tidy(Math.floor(tidy(lo / step)) * step)),
    Math.min(entry.max, tidy(Math.ceil(tidy(hi / step)) * step))];
}

/** The from and to a sweep of the setting `entry` starts with, around its `current` value: its
 *  whole range, but from its minimum to four times the value (12 steps at least) where the schema's
 *  maximum is only a cap far above the default (counts, sizes, gates: min_inliers 4..1000, 10 by
 *  default). Swept whole in 13 steps, 4, 87, 170, …, only 4 worked there, and that least strict
 *  gate was offered as the centre. */
function sweepRange(entry, current) {
  const step = stepOf(entry);
  if (entry.max <= 10 * Math.max(Math.abs(entry.default ?? entry.max), step)) return [entry.min, entry.max];
  return onSteps([entry.min, Math.max(4 * (current ?? entry.default), entry.min + 12 * step)], entry);
}

/** The sweep's fields for the setting `name`: its range (sweepRange) and its bounds and step, or
 *  the arrow keys would step within the previous setting's. */
function showSweepRange(name) {
  const entry = state.schema.find((e) => e.name === name);
  const [lo, hi] = sweepRange(entry, state.settings[name]);
  for (const [id, value] of [["#sweep-lo", lo], ["#sweep-hi", hi]]) {
    Object.assign($(id), { min: entry.min, max: entry.max, step: entry.step ?? "any", value });
  }
}

function fillSweepParams() {
  const select = $("#sweep-param");
  fill(select, state.schema.filter((e) => e.type === "float" || e.type === "int")
    .map((e) => el("option", { value: e.name }, e.name)));
  select.value = "threshold";
  showSweepRange(select.value);
  select.onchange = () => showSweepRange(select.value);
}

/** Sweep as the sweep's fields say, after setting them to `again` ({param, range: [lo, hi]}) if given. */
async function runSweep(again = null) {
  if (sweeping) return;
  if (again) {
    $("#sweep-param").value = again.param;
    showSweepRange(again.param);
    [$("#sweep-lo").value, $("#sweep-hi").value] = again.range;
  }
  const button = $("#run-sweep");
  const param = $("#sweep-param").value;
  const query = new URLSearchParams({
    param, lo: $("#sweep-lo").value, hi: $("#sweep-hi").value, steps: $("#sweep-steps").value,
  });
  sweeping = true;
  button.disabled = true;
  button.textContent = "sweeping…";
  try {
    // The settings it ran under are those of when it was sent: a change while it runs is one since.
    const key = sweepKey(state.settings, param);
    sweep = { ...(await get(`/api/sweep?${query}`)), key };
    renderSweep();
  } catch (err) {
    report(err);
  } finally {
    sweeping = false;
    button.disabled = false;
    button.textContent = "run sweep";
  }
}

/**
 * What the sweep's working band says of `sweep.param` (schema `entry`), in `digits` decimals, and
 * the one thing to do next: {parts} to show, and the `centre` offered (or null). Its centre, which
 * has working values either side, is offered only when both of the band's edges were seen:
 * - a band reaching an end of the values swept that is not the setting's own limit may go on
 *   beyond it: its centre is not known, so a sweep reaching further that way is offered;
 * - a band of one or two values swept has its edges somewhere between them and the failing values
 *   next to them, its centre at an edge: a sweep between those neighbours is offered, or, when no
 *   value lies between them, the value that works, as what it is.
 */
function bandVerdict(sweep, entry, digits) {
  const xs = sweep.values, n = xs.length, [lo, hi] = sweep.band;
  const i0 = xs.indexOf(lo), i1 = xs.indexOf(hi);
  const name = sweep.param, v = (x) => fmt(x, digits);
  const band = el("b", {}, lo === hi ? v(lo) : `${v(lo)}–${v(hi)}`);
  const rerun = (range, why) => el("button.primary", {
    type: "button", title: `Run the sweep again over ${v(range[0])}–${v(range[1])} ${why}`,
    onclick: () => runSweep({ param: name, range }),
  }, `sweep ${v(range[0])}–${v(range[1])}`);
  const apply = (label, title) => el("button.primary", {
    type: "button", title, onclick: () => setSetting(name, sweep.centre) }, label);

  const below = i0 === 0 && xs[0] > entry.min, above = i1 === n - 1 && xs[n - 1] < entry.max;
  if (below || above) {
    const width = xs[n - 1] - xs[0];
    const range = onSteps([below ? xs[0] - width : xs[0], above ? xs[n - 1] + width : xs[n - 1]], entry);
    const ends = [below && `below ${v(xs[0])}`, above && `above ${v(xs[n - 1])}`].filter(Boolean).join(" and ");
    return { centre: null, parts: [
      el("span.warn", {}, `${name} works over `, band, ` and perhaps ${ends}, where the sweep stopped: `
        + "its centre is not known yet"),
      rerun(range, `to find where ${name} stops working`)] };
  }
  if (i1 - i0 < 2) {
    const range = onSteps([xs[Math.max(i0 - 1, 0)], xs[Math.min(i1 + 1, n - 1)]], entry);
    const swept = xs.filter((x) => range[0] <= x && x <= range[1]).length;
    const only = `${name} works only at `;
    if (Math.round((range[1] - range[0]) / stepOf(entry)) + 1 > swept) {   // values not swept lie between
      return { centre: null, parts: [
        el("span.warn", {}, only, band, ` of the values swept: where it stops working lies between `
          + `${v(range[0])} and ${v(range[1])}`),
        rerun(range, "to see how far the values that work reach")] };
    }
    return { centre: null, parts: [
      el("span.warn", {}, only, band, ": no value has working values either side"),
      apply(`apply ${v(sweep.centre)}`, `Set ${name} to ${v(sweep.centre)}: no other value swept works`)] };
  }
  return { centre: sweep.centre, parts: [
    el("span", {}, `${name} works over `, band, ", centre ", el("b.suggested", {}, v(sweep.centre))),
    apply("apply centre", `Set ${name} to the centre of the working band`)] };
}

function renderSweep() {
  const info = $("#sweep-info");
  const canvas = $("#sweep");
  const labelled = state.images.some((i) => i.expected !== null);
  $("#run-sweep").disabled = !labelled || sweeping;
  canvas.hidden = !sweep;
  if (!labelled) {
    fill(info, el("span.muted", {}, "Give images an expected label (above, or when uploading) to sweep."));
    return;
  }
  if (!sweep) { fill(info); return; }
  const entry = state.schema.find((e) => e.name === sweep.param);
  const digits = entry.type === "int" ? 0 : 2;
  const verdict = sweep.band ? bandVerdict(sweep, entry, digits)
    : { centre: null, parts: [el("span.warn", {}, `no ${sweep.param} value gets every labelled image right`)] };
  drawSweep(canvas, { ...sweep, centre: verdict.centre }, state.settings[sweep.param], digits);   // marked where offered
  describeChart(canvas, sweepScale());
  fill(info,
    el("span", {}, el("i.swatch.correct"), `correct of ${sweep.labelled} labelled`),
    el("span", {}, el("i.swatch.margin"), "smallest margin"),
    ...verdict.parts,
    sweep.failed.some((n) => n) ? el("span.warn", {},
      `${plural(Math.max(...sweep.failed), "image")} could not be run at some values (counted as wrong)`) : null,
    sweep.key !== sweepKey(state.settings, sweep.param)
      ? el("span.warn", {}, "other settings changed since: run again") : null);
}

// ---- the charts as sliders: a click sets the value under it, and so do the keys

/** What the histogram sets, over the values it shows. */
const histogramScale = () => ({ name: "threshold", lo: 0, hi: 1, what: "threshold histogram" });

/** What the sweep chart sets (the setting swept), over the values it shows; null before a sweep. */
const sweepScale = () => sweep && {
  name: sweep.param, lo: sweep.values[0], hi: sweep.values[sweep.values.length - 1], what: "sweep chart" };

// A focused chart's keys: steps of the setting each takes it by (ten with Shift), as a slider's do.
const STEP_KEYS = { ArrowLeft: -1, ArrowDown: -1, ArrowRight: 1, ArrowUp: 1 };

/** The ends of the slider a chart over `scale` is, with the setting at `now`: the chart's, stretched
 *  to `now` when it lies beyond them (a sweep over part of the setting's range), as a slider's value
 *  is never outside its range. */
function sliderEnds({ lo, hi }, now) {
  return typeof now === "number" ? [Math.min(lo, now), Math.max(hi, now)] : [lo, hi];
}

/** The value the key of keydown `e` takes the setting of `scale` to; null for a key a chart does not
 *  take. Arrows step on from the value the form holds, not yet answered, within the chart; from a
 *  value beyond it, the key toward it goes to its nearest end and the key away from it keeps the value
 *  (clamped to the chart, → from above a sweep lowered the setting). Home and End go to the slider's ends. */
function keyedValue(e, scale) {
  if (e.altKey || e.ctrlKey || e.metaKey) return null;
  const now = settingValue(scale.name);
  const [min, max] = sliderEnds(scale, now);
  if (e.key === "Home") return min;
  if (e.key === "End") return max;
  const direction = STEP_KEYS[e.key];
  if (!direction) return null;
  const entry = state.schema.find((x) => x.name === scale.name);
  const from = now ?? scale.lo;   // a setting off (null) starts from the chart's low end
  const to = Math.min(scale.hi, Math.max(scale.lo, from + direction * (e.shiftKey ? 10 : 1) * stepOf(entry)));
  return direction * (to - from) < 0 ? from : to;
}

/** Say on `canvas`, a chart drawn over `scale`, what it does and the value it marks now (a slider's
 *  ARIA attributes, over `sliderEnds`), so that a keyboard or screen reader user finds it as a control. */
function describeChart(canvas, scale) {
  const { name, lo, hi, what } = scale;
  const now = state.settings[name];
  const off = now === null || now === undefined;
  const beyond = !off && (now < lo || now > hi) ? `, beyond the chart's ${settingText(name, lo)}–${settingText(name, hi)}` : "";
  const text = (off ? "off" : settingText(name, now)) + beyond;
  canvas.setAttribute("aria-label", `${what}: click, or press ← → (with Shift, ten steps), Home or End, `
    + `to set ${name}; now ${text}`);
  const [min, max] = sliderEnds(scale, now);
  canvas.setAttribute("aria-valuemin", min);
  canvas.setAttribute("aria-valuemax", max);
  canvas.setAttribute("aria-valuetext", text);
  if (typeof now === "number") canvas.setAttribute("aria-valuenow", now);
  else canvas.removeAttribute("aria-valuenow");
}

/** Clicking a chart sets the value there: faster than finding the slider. The keyboard does the
 *  same on a focused chart (`keyedValue`), by the same path; the keys it takes are not the detail
 *  view's (← → there step through the images). */
function bindChart(canvas, scale) {
  canvas.addEventListener("click", (e) => {
    const s = scale();
    if (s) setSetting(s.name, valueAt(canvas, e.clientX, s.lo, s.hi));
  });
  canvas.addEventListener("keydown", (e) => {
    const s = scale();
    const value = s && keyedValue(e, s);
    if (value === null || value === undefined) return;
    e.preventDefault();   // nor does the panel scroll, nor the detail step to another image
    if (value !== settingValue(s.name)) setSetting(s.name, value);
  });
}

// ---- wiring

function step(delta) {
  const ids = state.images.map((i) => i.id);
  const next = ids[(ids.indexOf(state.selected) + delta + ids.length) % ids.length];
  if (next) choose(next);
}

export function initDetail() {
  const area = input.fig.querySelector(".stage-img");
  area.id = "drag-area";
  area.append(el("div.drag-rect", { id: "drag-rect", hidden: true }));
  input.fig.classList.add("input-stage");
  $("#input-slot").replaceWith(input.fig);
  textCheck.fig.classList.add("text-stage");
  fill($("#stages"), ...stages.map((s) => s.figure.fig), textCheck.fig);
  bindDrag();
  $("#calib-box").addEventListener("change", (e) => typeBox(e.target));
  bindChart($("#histogram"), histogramScale);
  bindChart($("#sweep"), sweepScale);
  fillSweepParams();
  $("#run-sweep").onclick = () => runSweep();
  $("#prev").onclick = () => step(-1);
  $("#next").onclick = () => step(1);
  $("#detail-close").onclick = () => select(null);
  document.addEventListener("keydown", (e) => {
    // Keys typed in a field, or in the Camera dialog over the page, are not for the detail view,
    // nor those a control took (a chart's arrows).
    if (e.defaultPrevented || e.target.closest("input, select, textarea, dialog") || !state.selected) return;
    if (e.key === "ArrowLeft") step(-1);
    else if (e.key === "ArrowRight") step(1);
    else if (e.key === "Escape") select(null);
  });
  // Labels chosen in quick succession (arrow keys on the select) go one after the other: sent at
  // once, the server could take them in either order and keep an earlier one than the select shows.
  let labelling = Promise.resolve();
  $("#detail-expected").onchange = (e) => {
    const id = detail.id, expected = e.target.value || null;
    labelling = labelling.then(async () => {
      try {
        await api("PATCH", `/api/images/${id}`, { expected });
      } catch (err) {
        report(err);
      }
      refreshImages();
    });
  };
  on("select", (id) => (id ? load(id) : close()));
  buildMatchRows();
  on("library", () => {
    buildMatchRows();
    if (detail) load(detail.id);
  });
  on("images", () => {
    const img = state.images.find((i) => i.id === state.selected);
    if (state.selected && !img) select(null);
    else if (img && keyOf(img) !== shownKey) load(img.id);
    renderSweep();
  });
  on("settings", () => {   // the threshold markers move
    renderCalib();
    renderSweep();
  });
  on("camera", () => detail && load(detail.id));
  new ResizeObserver(() => { renderCalib(); renderSweep(); }).observe($("#calib"));
}
