// Entry point: load the initial state, wire the views, and follow the server's event stream.

import { get, latestGet } from "./api.js";
import { initCamera } from "./camera.js";
import { initDetail } from "./detail.js";
import { initFlights, refreshFlights } from "./flights.js";
import { choose, initGallery, refreshImages } from "./gallery.js";
import { initLibrary, loadLibrary } from "./library.js";
import { initMap, loadMap } from "./map.js";
import { reloadScene } from "./scene.js";
import { apply as applySettings, initSettings } from "./settings.js";
import { emit, on, select, state } from "./store.js";
import { $, report } from "./ui.js";

function showProgress({ running, done, total }) {
  const pill = $("#run-status");
  pill.classList.toggle("busy", running);
  pill.textContent = running ? `re-running ${done}/${total}` : "up to date";
  $("#run-progress").style.width = running && total ? `${(100 * done) / total}%` : "0";
}

/** `bytes` for people, as the server words them in its messages: "61.2 MB", "12.9 GB". */
const memoryText = (bytes) => (bytes >= 1e9 ? `${Number((bytes / 1e9).toPrecision(3))} GB`
  : `${Number((bytes / 1e6).toPrecision(3))} MB`);

/** The top bar's memory figure from a GET /api/health answer: how close uploads are to being refused. */
function showMemory({ memory_held_bytes: held, memory_limit_bytes: limit }) {
  $("#memory").textContent = `memory ${memoryText(held)} of ${memoryText(limit)}`;
}

const getHealth = latestGet("/api/health");   // images held change in bursts: the figures can cross

async function loadHealth() {
  try {
    const { body, newest } = await getHealth();
    if (newest) showMemory(body);
  } catch (err) {
    report(err);
  }
}

/** The top bar's height, as --topbar-height for style.css: the messages show under it, and it takes
 *  a second line in a narrow window. */
function followTopbarHeight() {
  const bar = $(".topbar");
  new ResizeObserver(() => document.documentElement.style.setProperty("--topbar-height", `${bar.offsetHeight}px`))
    .observe(bar);
}

/** Everything the event stream could have told us while it was down. */
async function resync() {
  try {
    applySettings(await get("/api/settings"), true);
    loadLibrary().then(refreshImages, report);
    refreshFlights();
    loadMap().catch(report);
    emit("camera");
    emit("calibration", null);   // an open Camera dialog shows the calibration again
    loadHealth();   // a restarted server may have another memory limit
  } catch (err) {
    report(err);
  }
}

function listen() {
  const source = new EventSource("/api/events");
  const live = $("#live");
  const handle = (fn) => (e) => {
    try { fn(JSON.parse(e.data || "null")); } catch (err) { report(err); }
  };
  let opened = false;
  source.onopen = () => {
    live.className = "live on";
    live.title = "live: following server events";
    if (opened) { resync(); reloadScene(); }
    opened = true;
  };
  // EventSource reconnects by itself; say so instead of failing silently.
  source.onerror = () => {
    live.className = "live off";
    live.title = "event stream lost: reconnecting…";
  };
  source.addEventListener("settings", handle(applySettings));
  source.addEventListener("results", handle((p) => { showProgress(p); refreshImages(); }));
  source.addEventListener("images", handle(refreshImages));
  source.addEventListener("library", handle(() => loadLibrary().then(refreshImages, report)));
  source.addEventListener("camera", handle(() => emit("camera")));
  source.addEventListener("calibration", handle((change) => emit("calibration", change)));
  source.addEventListener("flights", handle((progress) => emit("flights", progress)));
  source.addEventListener("map", handle((change) => emit("map", change)));
}

/** The image a `#image=<id>` link names, or null. */
const linkedImage = () => new URLSearchParams(location.hash.slice(1)).get("image") || null;

async function main() {
  window.addEventListener("unhandledrejection", (e) => report(e.reason));
  followTopbarHeight();
  const [health] = await Promise.all([get("/api/health"), loadLibrary()]);
  $("#app-version").textContent = `v${health.version}`;
  showMemory(health);
  await initSettings();
  initCamera();
  initLibrary();
  initGallery();
  initDetail();
  initFlights();
  initMap();
  const wanted = linkedImage();
  let autoOpen = true;
  let heldIds = null;   // the ids of the images the memory figure counts
  on("images", (images) => {
    // The memory held changes only with the images held.
    const ids = images.map((i) => i.id).join();
    if (ids !== heldIds) { heldIds = ids; loadHealth(); }
  });
  on("images", (images) => {
    // Open an image as soon as there is one, so the stages are visible without a click.
    if (!autoOpen || !images.length) return;
    autoOpen = false;
    if (state.selected) return;
    // The image a link names is brought into view as one chosen; the first is only opened.
    if (images.some((i) => i.id === wanted)) choose(wanted);
    else select(images[0].id);
  });
  // A link followed in this tab, or the hash edited, changes only the hash: show what it names.
  window.addEventListener("hashchange", () => choose(linkedImage()));
  refreshImages();
  listen();
}

main().catch(report);
