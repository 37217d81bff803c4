// The embedded 3D view: viser's client at /viser/ in an iframe. The server folds viser's control
// panel where it would cover much of the view (app/scene.py, fold_panel_in_small_view).

import { $ } from "./ui.js";

/** Load the embedded 3D scene afresh: its viser client gives up on a server that went away, and
 *  a restarted server is a new viser server anyway. */
export function reloadScene() {
  const scene = $("#scene");
  scene.src = scene.getAttribute("src");
}
