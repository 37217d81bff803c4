// The embedded 3D view: viser's client at /viser/ in an iframe (same origin, so the page may reach
// into its document).

import { $ } from "./ui.js";

// viser's control panel covers much of the page's narrow 3D view, so there it starts folded; a
// click on its connection status opens it (the pop-out tab shows it as viser does).
// - Under 576 px wide (the page's 3D column) viser shows it as a sheet fixed to the bottom right,
//   20em wide, up to 60 % of the height and open whenever it is built; a click on its handle folds
//   it. Each sheet is folded once: one the person opened stays open.
// - Wider (the 3D strip under the images, on screens up to 1280 px) as a floating window with a
//   "Minimize panel" button. The server could press that too, but for every viewer, the pop-out
//   tab's included; and viser opens the window again as it connects, so it is folded whenever it
//   shows open, until the person presses anything in the view.
const LOOK_MS = 200;         // how often to look for a panel to fold
const WATCH_MS = 30_000;     // how long after a load or resize: viser builds its layout when it likes
const QUIET_MS = 1000;       // how long after a fold viser's own focus calls are dropped
const HANDLE_TITLE = "3D view controls: click to open or fold";

const foldedSheets = new WeakSet();
let viewDoc = null;          // the view's document as last seen: a new one is a view loaded afresh
let touched = false;         // the person pressed something in `viewDoc`
let look = null;             // timer of the next look
let watchUntil = 0;          // Date.now() when looking stops
let quietUntil = 0;          // Date.now() until which the view may not take the focus (see follow)

/** The control that folds viser's open panel in `doc`, or null while there is none to fold. */
function foldControl(doc) {
  const style = (e) => doc.defaultView.getComputedStyle(e);
  const sheet = [...doc.querySelectorAll(".mantine-Paper-root")]
    .find((e) => style(e).position === "fixed" && style(e).bottom === "0px");
  if (sheet) {
    const handle = foldedSheets.has(sheet) ? null : sheet.querySelector('[style*="cursor: pointer"]');
    if (!handle) return null;
    foldedSheets.add(sheet);
    handle.title = HANDLE_TITLE;
    return handle;
  }
  return touched ? null : doc.querySelector('[aria-label="Minimize panel"]');
}

/** Fold viser's panel if it is open and not the person's doing, so the scene is seen whole. */
function foldControls() {
  clearTimeout(look);
  let doc = null;
  try {
    doc = $("#scene").contentDocument;
  } catch {
    return;   // not the page's origin (never so as served): nothing to fold
  }
  if (doc && doc !== viewDoc) follow(doc);
  const control = doc && foldControl(doc);
  if (control) {
    quietUntil = Date.now() + QUIET_MS;
    control.click();
  }
  if (Date.now() < watchUntil) look = setTimeout(foldControls, LOOK_MS);
}

/** Watch a freshly loaded view for the person's presses (its load event may have come before this
 *  page's script ran): once they press anything in it, its panel is theirs to fold or open.
 *
 *  viser focuses the window's expand button once it has folded (a new element). After a fold the
 *  page made, that focus is nobody's wish: it took the keyboard from wherever the person was and
 *  scrolled the page (which scrolls at 1280 px wide and less) down to the 3D view as it loaded.
 *  So the view's own focus calls are dropped for a moment after such a fold; Tab and clicks focus
 *  without them, so the view stays reachable from the keyboard. */
function follow(doc) {
  viewDoc = doc;
  touched = false;
  // Capturing: viser stops some presses from going further. A script's click() presses nothing.
  for (const kind of ["pointerdown", "keydown"]) doc.addEventListener(kind, () => { touched = true; }, true);
  const proto = doc.defaultView.HTMLElement.prototype;
  const focus = proto.focus;
  proto.focus = function (...args) {
    if (!touched && Date.now() < quietUntil) return;
    focus.apply(this, args);
  };
}

function watchControls() {
  watchUntil = Date.now() + WATCH_MS;
  foldControls();
}

/** Load the embedded 3D scene afresh: its viser client gives up on a server that went away, and
 *  a restarted server is a new viser server anyway. */
export function reloadScene() {
  const scene = $("#scene");
  scene.src = scene.getAttribute("src");
}

export function initScene() {
  const scene = $("#scene");
  scene.addEventListener("load", watchControls);
  // Also at once (its first report), and resized across viser's 576 px the view builds its panel anew.
  new ResizeObserver(watchControls).observe(scene);
}
