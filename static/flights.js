// Flights: a video or a ROS bag uploaded (with its upload, then processing, progress), listed, and
// shown in a view of its own: the frame with the tracked outlines and their state, a scrubber with
// play/pause, the camera position and the tracking state over time, and exports. The 3D scene
// (server side) draws the trajectory and follows the frame shown (PUT /api/flights/{id}/cursor).

import { api, get } from "./api.js";
import { CAMERA_FILE_FORMATS, intrinsicsText } from "./camera.js";
import { drawFlightPositions, drawFlightStates, valueAt } from "./charts.js";
import { on, select, signName } from "./store.js";
import { $, el, fill, plural, report, throttle, download } from "./ui.js";
import { uploadQueue } from "./uploads.js";

// What the server reads as a flight (app/flights.py FLIGHT_SUFFIXES).
const FLIGHT_FILE = /\.(mp4|m4v|avi|mkv|mov|webm|mpg|mpeg|wmv|flv|ts|mcap|db3|bag|zip)$/i;
export const FLIGHTS = {
  noun: "flight",
  accepts: (file) => file.type.startsWith("video/") || FLIGHT_FILE.test(file.name),
  refusal: (file) => `${file.name}: not a video or a ROS bag (.mcap, .db3, .bag, or a rosbag2 folder as .zip), skipped`,
};
export const isFlightFile = (file) => !file.type.startsWith("image/") && FLIGHTS.accepts(file);
const SVG = "http://www.w3.org/2000/svg";
const STATE_TEXT = { detected: "detected", tracked: "tracked" };
// Frames a second at most while playing: each frame is an image fetched from the server.
const MAX_PLAY_FPS = 30;

let flights = [];   // FlightOut, as the server lists them
const rows = new Map();   // id -> {row, parts}
let view = null;   // the flight shown: {flight, frames, label, index, playing}
let enqueue = null;
let camera = null;   // the camera file (File) sent with each flight queued, or null

const statusText = (f) => (f.status === "processing" ? `processing ${f.done}${f.total ? `/${f.total}` : ""}`
  : f.status === "error" ? "error" : f.status === "queued" ? "queued" : `${plural(f.frames, "frame")}`);

function makeRow(f) {
  const parts = { name: el("span.flight-name"), status: el("span.flight-status"), bar: el("div.bar") };
  const row = el("li.flight-row", { dataset: { id: f.id } }, parts.name, el("div.progress", {}, parts.bar), parts.status,
    el("button", { type: "button", class: "flight-open", onclick: () => openFlight(f.id) }, "open"),
    el("button.icon", {
      type: "button", title: "Remove this flight",
      onclick: async () => {
        try { await api("DELETE", `/api/flights/${f.id}`); } catch (err) { report(err); }
        if (view?.flight.id === f.id) closeFlight();
        refreshFlights();
      },
    }, "×"));
  return { row, parts };
}

function updateRow({ row, parts }, f) {
  row.dataset.status = f.status;
  parts.name.textContent = f.name;
  parts.name.title = f.error || f.warnings.join("\n") || f.name;
  parts.status.textContent = statusText(f);
  parts.status.title = f.error || "";
  const share = f.status === "processing" && f.total ? f.done / f.total : f.status === "queued" ? 0 : 1;
  parts.bar.style.width = `${Math.round(share * 100)}%`;
  row.classList.toggle("failed", f.status === "error");
  row.classList.toggle("selected", view?.flight.id === f.id);
}

function renderList() {
  const list = $("#flights");
  const seen = new Set();
  for (const f of flights) {
    seen.add(f.id);
    if (!rows.has(f.id)) rows.set(f.id, makeRow(f));
    updateRow(rows.get(f.id), f);
    list.append(rows.get(f.id).row);
  }
  for (const [id, { row }] of rows) if (!seen.has(id)) { row.remove(); rows.delete(id); }
}

async function loadFlights() {
  flights = (await get("/api/flights")).flights;
  renderList();
  if (view) {
    const now = flights.find((f) => f.id === view.flight.id);
    if (!now) closeFlight();
    else if (now.result_version !== view.flight.result_version && now.frames) openFlight(now.id, view.index);
  }
}

export const refreshFlights = throttle(() => loadFlights().catch(report), 250);

/** A `flights` event: every flight's progress; the list is fetched again when a run ended or flights came or went. */
function onProgress({ flights: progress }) {
  const known = new Map(flights.map((f) => [f.id, f]));
  let stale = progress.length !== flights.length;
  for (const p of progress) {
    const f = known.get(p.id);
    if (!f || f.result_version !== p.result_version) { stale = true; continue; }
    Object.assign(f, { status: p.status, done: p.done, total: p.total });
    updateRow(rows.get(f.id), f);
  }
  if (stale) refreshFlights();
}

// ---- the flight's view

/** The sign the view follows: the label seen on most frames. */
function mainLabel(frames) {
  const counts = new Map();
  for (const r of frames) for (const s of r.signs) counts.set(s.label, (counts.get(s.label) || 0) + 1);
  return [...counts].sort((a, b) => b[1] - a[1])[0]?.[0] ?? null;
}

/** Where a flight's camera came from, for the summary: a camera file by its name, not the server's path. */
const cameraSource = (source) => source.replace(/^file:.*[\\/]/, "file ");

const signOf = (record, label) => record.signs.find((s) => s.label === label) ?? null;
const positionOf = (sign) => (sign?.filtered_pose ?? sign?.pose)?.camera_position ?? null;

async function openFlight(id, index = 0) {
  try {
    const [flight, body] = await Promise.all([get(`/api/flights/${id}`), get(`/api/flights/${id}/frames`)]);
    stopPlaying();
    const frames = body.frames;
    const label = view?.flight.id === id && frames.some((r) => signOf(r, view.label)) ? view.label : mainLabel(frames);
    view = { flight, frames, label, index: -1, playing: false };
    select(null);   // the view takes the place of the image's detail
    $(".work-panel").classList.add("flight-open");
    const article = $("#flight");
    article.hidden = false;
    article.dataset.id = id;
    $("#flight-name").textContent = flight.name;
    $("#flight-summary").textContent = flight.status === "done" || frames.length
      ? `${plural(frames.length, "frame")}${flight.fps ? ` at ${flight.fps.toFixed(2)} fps` : ""}`
        + (flight.camera ? ` · ${intrinsicsText(flight.camera)}, ${cameraSource(flight.camera.source)}` : "")
      : statusText(flight);
    fill($("#flight-warnings"), [flight.error, ...flight.warnings].filter(Boolean).map((w) => el("li", {}, w)));
    const labels = [...new Set(frames.flatMap((r) => r.signs.map((s) => s.label)))];
    const pick = $("#flight-label");
    fill(pick, labels.map((l) => el("option", { value: l }, signName(l))));
    pick.value = label ?? "";
    pick.disabled = labels.length < 2;
    const scrub = $("#flight-scrub");
    scrub.max = Math.max(frames.length - 1, 0);
    scrub.disabled = !frames.length;
    $("#flight-play").disabled = !frames.length;
    for (const b of document.querySelectorAll("#flight-exports button")) b.disabled = !frames.length;
    renderList();
    if (frames.length) showFrame(Math.min(index, frames.length - 1));
    else drawCharts();
  } catch (err) {
    report(err);
  }
}

function closeFlight() {
  stopPlaying();
  view = null;
  $("#flight").hidden = true;
  $(".work-panel").classList.remove("flight-open");
  renderList();
}

const sendCursor = throttle(() => {
  if (view) api("PUT", `/api/flights/${view.flight.id}/cursor`, { frame: view.index }).catch(() => {});
}, 100);

/** Show frame `index`: its image, the signs' outlines and states, the charts' cursor; the 3D scene follows. */
function showFrame(index) {
  if (!view || index === view.index || index < 0 || index >= view.frames.length) return;
  view.index = index;
  const record = view.frames[index];
  const { flight } = view;
  $("#flight-scrub").value = index;
  $("#flight-img").src = `/api/flights/${flight.id}/frames/${index}/image?v=${flight.result_version}`;
  const overlay = $("#flight-overlay");
  overlay.setAttribute("viewBox", `0 0 ${flight.width} ${flight.height}`);
  overlay.replaceChildren(...record.signs.map((s) => {
    const g = document.createElementNS(SVG, "g");
    g.setAttribute("class", `outline ${s.state}`);
    const poly = document.createElementNS(SVG, "polygon");
    poly.setAttribute("points", s.corners.map(([x, y]) => `${x},${y}`).join(" "));
    const text = document.createElementNS(SVG, "text");
    const [x0, y0] = s.corners[0];
    text.setAttribute("x", x0);
    text.setAttribute("y", Math.max(12, y0 - 4));
    text.textContent = `${signName(s.label)} · ${STATE_TEXT[s.state]}`;
    g.append(poly, text);
    return g;
  }));
  $("#flight-time").textContent = `frame ${index} · ${record.time_s.toFixed(2)} s`;
  const sign = signOf(record, view.label);
  const position = positionOf(sign);
  $("#flight-state").dataset.state = sign?.state ?? "none";
  $("#flight-state").textContent = record.signs.length
    ? record.signs.map((s) => `${signName(s.label)}: ${STATE_TEXT[s.state]}`).join(" · ")
      + (position ? ` · camera at (${position.map((v) => v.toFixed(2)).join(", ")}) m` : "")
    : "no sign on this frame";
  drawCharts();
  sendCursor();
}

function drawCharts() {
  if (!view) return;
  const { frames, label } = view;
  const times = frames.map((r) => r.time_s);
  const t0 = times[0] ?? 0, t1 = times[times.length - 1] ?? 1;
  const cursor = view.index >= 0 ? times[view.index] : null;
  drawFlightPositions($("#flight-positions"), times, frames.map((r) => positionOf(signOf(r, label))), t0, t1, cursor);
  drawFlightStates($("#flight-states"), times, frames.map((r) => signOf(r, label)?.state ?? null), t0, t1, cursor);
}

/** The frame nearest to where a chart was clicked. */
function seekFromChart(canvas, clientX) {
  if (!view?.frames.length) return;
  const times = view.frames.map((r) => r.time_s);
  const t = valueAt(canvas, clientX, times[0], times[times.length - 1]);
  let best = 0;
  times.forEach((v, i) => { if (Math.abs(v - t) < Math.abs(times[best] - t)) best = i; });
  showFrame(best);
}

function stopPlaying() {
  if (view) view.playing = false;
  $("#flight-play").textContent = "▶ play";
}

/** Play from the frame shown at the flight's rate (at most MAX_PLAY_FPS), a frame waiting for the one before to load. */
function play() {
  if (!view?.frames.length) return;
  if (view.playing) { stopPlaying(); return; }
  if (view.index >= view.frames.length - 1) showFrame(0);
  view.playing = true;
  $("#flight-play").textContent = "❚❚ pause";
  const shown = view;
  const fps = Math.min(view.flight.fps || MAX_PLAY_FPS, MAX_PLAY_FPS);
  let last = performance.now();
  const tick = (now) => {
    if (view !== shown || !view.playing) return;
    const img = $("#flight-img");
    if (img.complete && now - last >= 1000 / fps) {
      last = now;
      if (view.index >= view.frames.length - 1) { stopPlaying(); return; }
      showFrame(view.index + 1);
    }
    requestAnimationFrame(tick);
  };
  requestAnimationFrame(tick);
}

function exportAs(format) {
  if (view) download(`/api/flights/${view.flight.id}/export?format=${format}`);
}

/** Take `file` (or null) as the camera file sent with the flights queued from now on. */
function chooseCamera(file) {
  camera = file;
  $("#flight-camera-name").textContent = file ? file.name : "camera file";
  $("#flight-camera-clear").hidden = !file;
}

/** A flight's upload form: the file, and the camera file chosen when it was queued. */
function flightForm(file) {
  const form = new FormData();
  form.append("file", file);
  if (camera) form.append("camera", camera);
  return form;
}

/** Send `files` (videos and bags) as flights, with a progress row each. */
export function addFlights(files) {
  enqueue(files);
}

export function initFlights() {
  enqueue = uploadQueue({
    list: $("#uploads"),
    url: "/api/flights",
    form: flightForm,
    done: () => { refreshFlights(); return "✓ added: processing"; },
    kind: FLIGHTS,
    ordered: false,
  });
  const picker = $("#flight-picker");
  picker.onchange = () => { enqueue(picker.files); picker.value = ""; };
  $("#flight-camera-pick").title = "The camera that filmed the next flights, sent with each (without one: the "
    + `workspace's camera, else a bag's CameraInfo, else the assumed field of view): ${CAMERA_FILE_FORMATS}`;
  const cameraPicker = $("#flight-camera");
  cameraPicker.onchange = () => { chooseCamera(cameraPicker.files[0] ?? null); cameraPicker.value = ""; };
  $("#flight-camera-clear").onclick = () => chooseCamera(null);
  $("#flight-close").onclick = closeFlight;
  $("#flight-play").onclick = play;
  $("#flight-scrub").addEventListener("input", (e) => { stopPlaying(); showFrame(Number(e.target.value)); });
  $("#flight-label").onchange = (e) => {
    if (!view) return;
    view.label = e.target.value;
    const index = view.index;
    view.index = -1;
    showFrame(index);
  };
  for (const canvas of [$("#flight-positions"), $("#flight-states")]) {
    canvas.addEventListener("click", (e) => { stopPlaying(); seekFromChart(canvas, e.clientX); });
  }
  for (const button of document.querySelectorAll("#flight-exports button")) {
    button.onclick = () => exportAs(button.value);
  }
  on("select", (id) => { if (id) closeFlight(); });   // an image chosen takes the view back
  on("flights", onProgress);
  window.addEventListener("resize", throttle(drawCharts, 100));
  refreshFlights();
}
