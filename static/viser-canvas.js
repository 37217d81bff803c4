// Loaded into viser's page (app/viser_proxy.py adds it), in the page's 3D view and in its pop-out
// tab alike. viser's client tells the server its canvas' size in device pixels and draws the camera
// labels at a size in CSS px: this tells the server how many device pixels that canvas has to the
// CSS px (the screen's devicePixelRatio, or fewer while viser lowers its resolution to keep its frame
// rate), by its size, so that the labels are laid out at their size on screen (app/scene.py).

const LOOK_MS = 300;   // how often to look: the window resized or zoomed, viser's resolution changed
let said = "";

function look() {
  const canvas = document.querySelector("canvas[data-engine]");   // three.js', where viser draws
  const cssWidth = canvas ? canvas.getBoundingClientRect().width : 0;
  if (!cssWidth || !canvas.width) return;
  const body = JSON.stringify({ width: canvas.width, height: canvas.height, px_per_css_px: canvas.width / cssWidth });
  if (body === said) return;
  said = body;
  // Not said again on failure: a server that comes back is a new viser server, whose page is loaded anew.
  fetch("/api/scene/canvas", { method: "PUT", headers: { "Content-Type": "application/json" }, body })
    .catch(() => {});
}

setInterval(look, LOOK_MS);
