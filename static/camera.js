// Camera intrinsics, which every pose depends on: the summary in the settings panel (with the
// assumed field of view while no camera is set) and the Camera dialog, which calibrates from
// chessboard photos (/api/calibration) or takes intrinsics typed in.

import { api, get, latestGet } from "./api.js";
import { barAt, drawViewErrors } from "./charts.js";
import { on, state } from "./store.js";
import { $, el, fill, fmt, debounce, download, plural, report, showModal, toast } from "./ui.js";
import { dropTarget, filesForm, uploadQueue } from "./uploads.js";

/** CameraIntrinsics.kind, for people. */
export const KIND_LABELS = {
  calibration: "chessboard calibration", file: "camera file", typed: "typed in",
  exif: "EXIF focal length", assumed: "assumed field of view",
};
const THUMB_SIDE = 320;
const PREVIEW_SIDE = 1280;

let camera = null;        // GET /api/camera
let calib = null;         // GET /api/calibration, the newest revision seen
let selected = null;      // id of the calibration photo in the preview
let picked = false;       // `selected` was clicked, not chosen for the person
let previewMode = "corners";
let hfovHeld = false;     // the slider is under the pointer: server answers must not yank it
let hfovTyped = false;    // a number typed in its field and not yet applied: server answers must not overwrite it
let cameraToken = 0;      // drops a camera answered after a newer request was sent
let reconnected = false;  // the event stream came back: the next calibration is shown whatever its revision

/** What a camera file may hold, for every picker of one (the workspace's camera, a flight's). */
export const CAMERA_FILE_FORMATS = "ROS camera_info YAML (file or ros2 topic echo output), OpenCV YAML/XML/JSON, "
  + "Kalibr camchain of one camera or {fx,fy,cx,cy,dist}";

/** "fx 520.1 fy 515.0 cx 318.0 cy 243.0 px @ 640×480" */
export const intrinsicsText = (cam) => `fx ${fmt(cam.fx, 1)} fy ${fmt(cam.fy, 1)} cx ${fmt(cam.cx, 1)} `
  + `cy ${fmt(cam.cy, 1)} px${cam.width ? ` @ ${cam.width}×${cam.height}` : ""}`;

/** Where `cam` came from, in a few words ("typed in", "upload:cam.yaml", "calibration: 12 views, …"). */
const sourceText = (cam) => (cam.kind === "typed" ? KIND_LABELS.typed : cam.source);

/** Why a pose computed with `cam` is approximate, or null when its intrinsics were measured. */
export function approximateNote(cam) {
  const fix = "Calibrate the camera (settings panel › Camera › calibrate…) for accurate poses.";
  if (cam.kind === "exif") {
    return `Intrinsics from the photo's ${cam.source}, without lens distortion and with the principal point `
      + `assumed central: distance and angles are approximate. ${fix}`;
  }
  if (cam.kind === "assumed") {
    return `No camera set and no usable EXIF focal length: ${cam.source}, so distance and angles are approximate. ${fix}`;
  }
  return null;
}

// ---- the settings panel's summary and the assumed field of view

/** Focal length, in the unit of `width`, of a horizontal field of view `hfov` (degrees) across `width`. */
const focalPx = (width, hfov) => width / 2 / Math.tan((hfov * Math.PI) / 360);

/** The first image whose size is known: the assumed camera is shown in its pixels. */
const sizedImage = () => state.images.find((i) => i.width);

function renderHfovNote(hfov) {
  const img = sizedImage();
  const px = img ? `, fx = fy ≈ ${fmt(focalPx(img.width, hfov), 0)} px at ${img.width} px wide` : "";
  // 35 mm equivalent as EXIF's FocalLengthIn35mmFilm (pipeline/exif.py): the image's diagonal
  // scaled to a 36 × 24 mm frame's, so a phone's "26 mm" agrees with its photos' EXIF.
  const [w, h] = img ? [img.width, img.height] : [36, 24];
  const mm = (focalPx(w, hfov) * Math.hypot(36, 24)) / Math.hypot(w, h);
  $("#hfov-note").textContent = `≈ ${fmt(mm, 0)} mm focal length (35 mm equivalent)${px}`;
}

function renderCamera() {
  const { camera: cam, assumed_hfov_deg: hfov, exif_images: exif } = camera;
  const info = $("#camera-info");
  info.classList.toggle("warn", !cam);
  const total = state.images.length;
  const about = cam && [intrinsicsText(cam), sourceText(cam)];
  info.textContent = cam
    ? about.join(" — ")
    : `No camera set, so poses are approximate: ${exif
      ? `${exif} of ${total} images use their EXIF focal length, the others` : "every image uses"} `
      + `the field of view assumed below. Calibrate for accurate poses.`;
  $("#assumed-fov").hidden = Boolean(cam);
  if (!hfovHeld) {
    $("#hfov").value = hfov;
    if (!hfovTyped) $("#hfov-num").value = hfov;
    renderHfovNote(hfov);
  }
  $("#dialog-camera").textContent = cam ? `in use: ${about.join(" · ")}`
    : "in use: none (EXIF or assumed field of view)";
}

// The toasts of the camera's warnings: a camera set or reset since, here or elsewhere, or images
// added or removed make them stale, and left up they piled up beside the new ones, none saying which
// camera or how many images it was about.
let cameraWarnings = [];

/** A camera's `warnings` (images held it does not fit, which the server keeps it for all the same)
 *  as toasts: for a camera the user has just set or reset (`fresh`) in place of those up; else those
 *  up that the camera still says are kept and the others replaced by what it says now (none come
 *  back once dismissed). */
function showCameraWarnings(warnings, fresh) {
  const up = cameraWarnings.filter((box) => box.isConnected);
  if (!fresh && !up.length) return;
  const text = (box) => box.querySelector(".toast-msg").textContent;
  const kept = fresh ? [] : up.filter((box) => warnings.includes(text(box)));
  for (const box of up) if (!kept.includes(box)) box.remove();
  const said = kept.map(text);
  cameraWarnings = [...kept, ...warnings.filter((w) => !said.includes(w)).map((w) => toast(w, "warn"))];
}

/** Shows the camera the server answers `request` with unless a newer request's answer is due,
 *  `done` as a toast, and its warnings (`showCameraWarnings`); errors as toasts. Whether the server
 *  took the camera. */
async function setCamera(request, done) {
  const token = ++cameraToken;
  try {
    const body = await request;
    if (done) toast(done, "info");
    const newest = token === cameraToken;
    if (newest) {
      camera = body;
      renderCamera();
    }
    // A camera just set says what it misfits even when a newer answer is due (the server's event
    // about it asks for the camera again, and that answer only keeps warnings up).
    if (newest || done) showCameraWarnings(body.warnings, Boolean(done));
    return true;
  } catch (err) {
    report(err);
    return false;
  }
}

const loadCamera = () => setCamera(get("/api/camera"));

const putHfov = debounce(async (hfov) => {
  const token = ++cameraToken;
  let body = null;
  try {
    body = await api("PUT", "/api/camera/assumed", { hfov_deg: hfov }, { keepalive: true });
  } catch (err) {
    report(err);
    hfovHeld = false;   // show the server's value again
  }
  if (token !== cameraToken) return;   // a newer answer is due, and shows the camera
  if (body) camera = body;
  renderCamera();
}, 200);

function bindSidebar() {
  const file = $("#camera-file");
  file.parentElement.title = CAMERA_FILE_FORMATS;
  file.onchange = async () => {
    const form = new FormData();
    form.append("file", file.files[0]);
    await setCamera(api("PUT", "/api/camera", form), `camera ${file.files[0].name} loaded`);
    file.value = "";
  };
  $("#camera-reset").onclick = () => setCamera(api("DELETE", "/api/camera"),
    "camera reset: each image takes its EXIF focal length, else the assumed field of view");
  const range = $("#hfov"), num = $("#hfov-num");
  const change = (value) => {
    const hfov = Number(value);
    range.value = num.value = hfov;
    renderHfovNote(hfov);
    putHfov(hfov);
  };
  range.addEventListener("pointerdown", () => { hfovHeld = true; });
  window.addEventListener("pointerup", () => { hfovHeld = false; });
  range.addEventListener("input", () => change(range.value));
  num.addEventListener("input", () => { hfovTyped = true; });
  num.addEventListener("focusout", () => {
    hfovTyped = false;
    num.value = range.value;   // left unchanged after typing (no change event): the value in use again
  });
  num.addEventListener("change", () => {
    hfovTyped = false;
    const [lo, hi] = [Number(num.min), Number(num.max)];
    // Said, not clamped: 200 quietly becoming 140 is a value nobody chose.
    if (num.value === "" || Number(num.value) < lo || Number(num.value) > hi) {
      toast(`the assumed field of view must be between ${lo} and ${hi}°; got ${num.value || "no number"}; `
        + `it stays ${range.value}°`, "error");
      num.value = range.value;
      return;
    }
    change(num.value);
  });
  // As for the settings form: a change still waiting out the debounce is sent when the page goes.
  window.addEventListener("pagehide", putHfov.flush);
}

// ---- the dialog: calibration from chessboard photos

const figureUrl = (id, overlay, side) => {
  const b = calib.board;
  // Figures change with the board searched for and, undistorted, with the result.
  const key = overlay === "undistorted" ? `${b.cols}x${b.rows}.${calib.revision}` : `${b.cols}x${b.rows}`;
  return `/api/calibration/views/${id}/image?overlay=${overlay}&max_side=${side}&v=${key}`;
};

/** Show a calibration state unless a newer one has been shown already (answers may cross). */
function show(body) {
  if (calib && !reconnected && body.revision < calib.revision) return;
  reconnected = false;
  calib = body;
  renderCalibration();
}

// A board search's progress keeps the revision: of its answers, the newest request's is shown.
const getCalibration = latestGet("/api/calibration");

async function loadCalibration() {
  try {
    const { body, newest } = await getCalibration();
    if (newest) show(body);
  } catch (err) {
    report(err);
  }
}

/** A calibration request whose answer is the new state; errors (a person can act on) as toasts. */
async function change(method, url, body) {
  try {
    show(await api(method, url, body));
    return true;
  } catch (err) {
    report(err);
    loadCalibration();   // the inputs show what the server holds again
    return false;
  }
}

function viewCard(view, index) {
  // other_size: found, but not the size most photos share, so no run can fit them (calib.size_mismatch).
  const flags = [view.found ? null : "board not found", view.other_size, view.outlier ? "outlier" : null,
    view.excluded ? "left out of the fit" : null].filter(Boolean);
  return el(`div.view-card${view.found ? "" : ".notfound"}${view.other_size ? ".othersize" : ""}`
    + `${view.outlier ? ".outlier" : ""}${view.excluded ? ".excluded" : ""}${view.id === selected ? ".selected" : ""}`, {
    tabIndex: 0, role: "button", dataset: { id: view.id, found: view.found },
    title: `${view.name} · ${view.width}×${view.height}${flags.length ? ` · ${flags.join(", ")}` : ""}`,
    onclick: () => selectView(view.id),
    onkeydown: (e) => { if (e.key === "Enter" || e.key === " ") { e.preventDefault(); selectView(view.id); } },
  },
  el("div.thumb-box", {}, el("img.thumb", { src: figureUrl(view.id, "corners", THUMB_SIDE), alt: "", decoding: "async" })),
  el("div.card-name", {}, `${index + 1}. ${view.name}`),
  el("div.card-stats", {}, view.found
    ? [el("span", {}, view.error_px === null ? "found" : `${fmt(view.error_px, 3)} px`),
      view.tilt_deg === null ? null : el("span", { title: "board tilt from facing the camera" }, `${fmt(view.tilt_deg, 0)}°`),
      view.outlier ? el("b.bad", {}, "outlier") : null, view.excluded ? el("span", {}, "dropped") : null]
    : el("span.bad", {}, "board not found")),
  view.other_size ? el("div.card-note.bad", {}, view.other_size) : null,
  el("button.icon.remove", {
    type: "button", title: "Remove this photo",
    onclick: async (e) => {
      e.stopPropagation();
      try { await api("DELETE", `/api/calibration/views/${view.id}`); } catch (err) { report(err); }
      loadCalibration();
    },
  }, "×"));
}

function renderSummary() {
  const found = calib.views.filter((v) => v.found).length;
  const r = calib.result;
  const b = calib.board;
  const search = calib.search;
  if (search) {   // the views and result are the old board's until it is done
    const bar = el("div.bar");
    bar.style.width = `${(100 * search.done) / search.total}%`;   // CSSOM: the page's CSP refuses style attributes
    fill($("#calib-summary"), el("p", { id: "calib-search", role: "status" },
      `searching the ${plural(search.total, "photo")} for the ${search.cols}×${search.rows} board: `
      + `${search.done} of ${search.total}`), el("div.progress", {}, bar));
    return;
  }
  if (!r) {
    // Photos of another size than most: said before any run, which would refuse them.
    const sizes = calib.size_mismatch;
    fill($("#calib-summary"), el("p.muted", {}, calib.unfitted
      ? `The ${plural(calib.views.length, "photo")} left could not be fitted again: ${calib.unfitted}`
      : calib.views.length
        ? `${plural(calib.views.length, "photo")}, the ${b.cols}×${b.rows} board found in ${found}`
          + (found < calib.min_views ? ` (at least ${calib.min_views} needed; 15–20 recommended)`
            : sizes ? "" : ": run the calibration")
          + (calib.hint ? `: ${calib.hint}` : "")
        : "No photos yet."),
    sizes && !calib.unfitted ? el("p.warn", { id: "calib-sizes" }, sizes) : null);
    return;
  }
  const cam = r.camera, sd = r.intrinsics_std;
  const outliers = calib.views.filter((v) => v.outlier).length;
  fill($("#calib-summary"), el("dl.pose", {},
    [el("dt", {}, "RMS"), el("dd", { id: "calib-rms" }, `${fmt(r.rms_px, 3)} px from ${r.used} of ${calib.views.length} photos`
      + (outliers ? ` · ${plural(outliers, "outlier")} (> ${fmt(r.outlier_threshold_px, 2)} px)` : ""))],
    // The server's advice (app/calibration.py, page_outlier_advice), shown as it comes: one copy of
    // what to do about outliers (dropped once; those the refit flags are to retake or remove) serves
    // the CLI and the page.
    r.outlier_advice ? [el("dt", {}, "outliers"), el("dd.plain", { id: "calib-advice" }, r.outlier_advice)] : null,
    ...["fx", "fy", "cx", "cy"].map((k) => [el("dt", {}, k), el("dd", { dataset: { key: k } }, `${fmt(cam[k], 2)} ± ${fmt(sd[k], 2)} px`)]),
    [el("dt", {}, "distortion"), el("dd", {}, cam.dist.map((d) => fmt(d, 4)).join(" "))],
    [el("dt", {}, "image size"), el("dd", {}, `${cam.width}×${cam.height}`)],
    [el("dt", {}, "board"), el("dd", {}, `${b.cols}×${b.rows} inner corners, ${fmt(b.square_m * 1000, 1)} mm squares`)]));
}

function renderChart() {
  const r = calib.result;
  $("#calib-chart-box").hidden = !r;
  if (r) drawViewErrors($("#calib-chart"), calib.views, r, calib.views.findIndex((v) => v.id === selected));
}

function renderPreview() {
  const view = calib.views.find((v) => v.id === selected);
  $("#calib-preview-box").hidden = !view;
  if (!view) return;
  if (!calib.result) previewMode = "corners";
  for (const button of document.querySelectorAll("#preview-mode button")) {
    button.classList.toggle("active", button.value === previewMode);
    button.disabled = button.value === "undistorted" && !calib.result;
  }
  $("#preview-name").textContent = `· ${view.name}`;
  const url = figureUrl(view.id, previewMode, PREVIEW_SIDE);
  if ($("#calib-preview").getAttribute("src") !== url) $("#calib-preview").src = url;
}

function renderCalibration() {
  const b = calib.board;
  // During a search the board is still the old one: the fields keep the size being searched for.
  const { cols, rows } = calib.search ?? b;
  for (const [id, value] of [["#board-cols", cols], ["#board-rows", rows], ["#board-square", b.square_m * 1000]]) {
    if (document.activeElement !== $(id)) $(id).value = Number(value.toFixed(3));
  }
  const current = calib.views.find((v) => v.id === selected);
  if (!current || (!picked && !current.found)) {
    picked = false;
    selected = (calib.views.find((v) => v.found) ?? calib.views[0])?.id ?? null;
  }
  fill($("#calib-views"), ...calib.views.map(viewCard));
  $("#calib-empty").hidden = calib.views.length > 0;
  const found = calib.views.filter((v) => v.found).length;
  // A fit waits for the search and then fits the new board; the old result is dropped once it ends.
  const searching = Boolean(calib.search);
  $("#calib-run").disabled = searching || found < calib.min_views || Boolean(calib.size_mismatch);
  // Dropped once already: a second drop refits to the same result (see renderSummary).
  $("#calib-drop").disabled = searching || calib.views.some((v) => v.excluded) || !calib.views.some((v) => v.outlier);
  $("#calib-apply").disabled = $("#calib-yaml").disabled = searching || !calib.result;
  renderSummary();
  fill($("#calib-warnings"), ...(calib.result?.warnings ?? []).map((w) => el("li", {}, w)));
  renderChart();
  renderPreview();
}

function selectView(id) {
  selected = id;
  picked = true;
  for (const card of document.querySelectorAll("#calib-views .view-card")) {
    card.classList.toggle("selected", card.dataset.id === id);
  }
  renderChart();
  renderPreview();
}

const run = (dropOutliers) => change("POST", "/api/calibration/run", { drop_outliers: dropOutliers });

function bindCalibration() {
  const enqueue = uploadQueue({
    list: $("#calib-uploads"),
    url: "/api/calibration/images",
    form: (file) => filesForm(file),
    done: (body) => {
      show(body);
      // Photos are listed in the order chosen, not as they land, and names may repeat: the
      // answer names the photo it added.
      return body.views.find((v) => v.id === body.added[0])?.found
        ? "✓ board found" : "✓ added, but the board was not found";
    },
    // Once a batch is in, fit at once when it can be: the chart is what people add photos for.
    idle: () => {
      if (calib && calib.views.filter((v) => v.found).length >= calib.min_views && !calib.size_mismatch) run(false);
    },
  });
  const picker = $("#calib-picker");
  picker.onchange = () => { enqueue(picker.files); picker.value = ""; };
  dropTarget($("#camera-dialog"), (files) => {
    showTab("calibrate");
    enqueue(files);
  });
  const putBoard = () => {
    const square = $("#board-square").value, most = calib.max_square_m * 1000;
    // The field is in millimetres; the server's message for this would speak of metres.
    if (!(Number(square) > 0 && Number(square) <= most)) {
      report(new Error(`square size must be a positive number of millimetres up to ${most}; `
        + `got ${square || "nothing"}`));
      loadCalibration();
      return;
    }
    // A new corner count searches every photo again before this answer comes: meanwhile `calibration`
    // events say how far it has come.
    change("PUT", "/api/calibration/board", {
      cols: Number($("#board-cols").value), rows: Number($("#board-rows").value), square_m: Number(square) / 1000,
    });
  };
  for (const id of ["#board-cols", "#board-rows", "#board-square"]) $(id).addEventListener("change", putBoard);
  $("#calib-run").onclick = () => run(false);
  $("#calib-drop").onclick = () => run(true);
  $("#calib-apply").onclick = () => setCamera(api("POST", "/api/calibration/apply"),
    "calibrated camera applied: every image is being re-run with it");
  $("#calib-yaml").onclick = () => download("/api/calibration/camera.yaml");
  $("#calib-clear").onclick = () => {
    if (calib?.views.length && confirm(`Remove all ${plural(calib.views.length, "calibration photo")}?`)) {
      change("DELETE", "/api/calibration");
    }
  };
  $("#calib-chart").addEventListener("click", (e) => {
    const view = calib.views[barAt(e.currentTarget, e.clientX, calib.views.length)];
    if (view) selectView(view.id);
  });
  for (const button of document.querySelectorAll("#preview-mode button")) {
    button.onclick = () => { previewMode = button.value; renderPreview(); };
  }
  new ResizeObserver(() => calib && renderChart()).observe($("#calib-chart-box"));
}

// ---- the dialog: intrinsics typed in

const TYPED = ["fx", "fy", "cx", "cy", "width", "height"];
// ROS's roi and binning, as camera files and PUT /api/camera name them: the images are that part of
// the sensor whose intrinsics and size TYPED then are.
const ROI = ["x_offset", "y_offset", "width", "height"];
const BINNING = ["binning_x", "binning_y"];

// Distortion belongs to the lens it was calibrated with: filled in with the rest of a camera, it
// says where it came from until it is typed over or cleared, and warns once the other fields are
// changed (numbers for another camera) while it is still there.
let distFrom = null;   // where the distortion in the form was filled in from, while it holds that

function showDistOrigin(changed = false) {
  const origin = $("#typed-dist-origin");
  origin.hidden = !distFrom;
  if (!distFrom) return;
  origin.classList.toggle("warn", changed);
  $("#typed-dist-note").textContent = changed
    ? `distortion kept from ${distFrom}: clear it unless it is the same lens`
    : `distortion from ${distFrom}`;
}

/** Fill the form in with `cam` (a camera file's keys: fx … height, dist, and roi and binning for part
 *  of a sensor). */
function putTyped(cam) {
  // Rounded: a thousandth of a pixel, six significant digits of distortion, are beyond any calibration.
  for (const k of TYPED) $(`#typed-${k}`).value = cam[k] === null ? "" : Number(cam[k].toFixed(3));
  $("#typed-dist").value = cam.dist.map((d) => Number(d.toPrecision(6))).join(" ");
  for (const k of ROI) $(`#typed-roi-${k}`).value = cam.roi?.[k] ?? "";
  for (const k of BINNING) $(`#typed-${k}`).value = cam[k] ?? "";
  $("#typed-window").open = Boolean(cam.roi);
}

async function fillTyped() {
  const result = calib?.result?.camera;
  const inUse = camera?.camera;
  const img = sizedImage();
  if (result) putTyped(result);
  else if (inUse) {
    // As its file gives it: GET /api/camera has the intrinsics of the images, not the sensor's with its roi.
    try {
      putTyped(await get("/api/camera/file"));
    } catch (err) {
      report(err);
      return;
    }
  } else if (img) {   // the assumed camera of the first image
    const f = focalPx(img.width, camera.assumed_hfov_deg);
    putTyped({ fx: f, fy: f, cx: img.width / 2, cy: img.height / 2, width: img.width, height: img.height, dist: [] });
  }
  const cam = result ?? inUse;
  distFrom = cam?.dist.length ? (result ? "the calibration result" : `the camera in use (${sourceText(cam)})`) : null;
  showDistOrigin();
}

/** The roi and binning typed, as PUT /api/camera takes them; null for a roi given in part. */
function typedWindow(value) {
  const roi = Object.fromEntries(ROI.map((k) => [k, value(`roi-${k}`)]));
  const given = ROI.filter((k) => roi[k] !== null).length;
  if (given && given < ROI.length) return null;
  return { ...(given ? { roi } : {}), ...Object.fromEntries(BINNING.map((k) => [k, value(k)])) };
}

function bindDistOrigin() {
  $("#typed-dist").addEventListener("input", () => { distFrom = null; showDistOrigin(); });
  for (const k of TYPED) $(`#typed-${k}`).addEventListener("input", () => showDistOrigin(true));
  $("#typed-dist-clear").onclick = () => {
    $("#typed-dist").value = "";
    distFrom = null;
    showDistOrigin();
    $("#typed-dist").focus();
  };
}

function bindTyped() {
  bindDistOrigin();
  $("#typed-fill").onclick = fillTyped;
  $("#typed-form").addEventListener("submit", async (e) => {
    e.preventDefault();
    const dist = $("#typed-dist").value.split(/[\s,]+/).filter(Boolean).map(Number);
    if (dist.some(Number.isNaN)) {
      toast("distortion: give numbers separated by spaces, in OpenCV's order k1 k2 p1 p2 k3", "error");
      return;
    }
    const value = (k) => ($(`#typed-${k}`).value === "" ? null : Number($(`#typed-${k}`).value));
    const part = typedWindow(value);
    if (!part) {
      toast("roi: give its x offset, y offset, width and height, in px of the whole sensor, or none of them", "error");
      return;
    }
    const body = Object.fromEntries(TYPED.map((k) => [k, value(k)]));
    const applied = await setCamera(api("PUT", "/api/camera", { ...body, dist, ...part }),
      "typed intrinsics applied: every image is being re-run with them");
    if (applied) { distFrom = null; showDistOrigin(); }   // it is the camera in use now
  });
}

// ---- wiring

function showTab(name) {
  for (const button of document.querySelectorAll("#camera-tabs button")) {
    button.classList.toggle("active", button.value === name);
  }
  $("#tab-calibrate").hidden = name !== "calibrate";
  $("#tab-typed").hidden = name !== "typed";
  if (name === "typed" && $("#typed-fx").value === "") fillTyped();
}

export function initCamera() {
  bindSidebar();
  bindCalibration();
  bindTyped();
  const dialog = $("#camera-dialog");
  $("#camera-open").onclick = () => {
    showTab("calibrate");
    showModal(dialog);
    loadCalibration();
  };
  $("#camera-close").onclick = () => dialog.close();
  for (const button of document.querySelectorAll("#camera-tabs button")) button.onclick = () => showTab(button.value);
  on("camera", loadCamera);
  // The calibration is one for everyone using the server: an open dialog shows what another page
  // changed (a photo removed, a run, a new board), and how far a board search has come.
  on("calibration", (change) => {
    // null: the event stream is back, maybe from a restarted server, whose revisions start again at 0.
    if (change === null) reconnected = true;
    if (dialog.open) loadCalibration();
  });
  // The load below counts the images the page knows of (none yet); it cannot wait for the first
  // images event, which never comes when GET /api/images fails.
  let imageCount = state.images.length;
  on("images", (images) => {
    // Only a new or removed image changes how many use their EXIF focal length.
    if (images.length !== imageCount) { imageCount = images.length; loadCamera(); }
  });
  loadCamera();
}
