// Loaded into viser's page (app/viser_proxy.py adds it), in the page's 3D view and in its pop-out
// tab alike. viser's client tells the server its canvas' size in device pixels and draws the camera
// labels at a size in CSS px: this tells the server how many device pixels that canvas has to the
// CSS px (the screen's devicePixelRatio, or fewer while viser lowers its resolution to keep its frame
// rate), so that the labels are laid out at their size on screen (app/scene.py). It names its viewer
// as the server named it (window.signposeViewer, which app/scene.py's name_viewer sets anew on each
// connection): two viewers' canvases of one size in device px may be of two sizes in CSS px.

const LOOK_MS = 300;   // how often to look: the window resized or zoomed, viser's resolution changed
let said = "";
let saidTo = null;     // the viewer `said` was said of: a new connection is told again

function look() {
  const canvas = document.querySelector("canvas[data-engine]");   // three.js', where viser draws
  const cssWidth = canvas ? canvas.getBoundingClientRect().width : 0;
  const viewer = window.signposeViewer;
  if (!cssWidth || !canvas.width || !viewer) return;
  const body = JSON.stringify({ width: canvas.width, height: canvas.height, px_per_css_px: canvas.width / cssWidth });
  if (body === said && viewer === saidTo) return;
  [said, saidTo] = [body, viewer];
  // Not said again on failure: a server that comes back names the viewer again as it reconnects.
  fetch(`/api/scene/canvas?viewer=${viewer.id}`, { method: "PUT", headers: { "Content-Type": "application/json" }, body })
    .catch(() => {});
}

setInterval(look, LOOK_MS);
