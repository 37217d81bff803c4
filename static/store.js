// The page's copy of server state. Modules read `state` and listen with `on`; only the code
// that fetched new data calls `emit`, so each view re-renders from one place.

export const state = {
  schema: [],          // settings_schema(): one entry per parameter
  settings: {},        // current server settings
  version: 0,          // settings_version of `settings`
  presets: {},
  library: [],         // [{id, name, text, ...}]
  images: [],          // [ImageSummary] in the order the files were chosen
  selected: null,      // id of the image in the detail view
};

const bus = new EventTarget();

/** Events: settings, library, images, select, camera, calibration, detail (an image's detail drawn),
 *  flights (the server's flights event: their progress), map (the sign map held changed). */
export function emit(name, detail) {
  bus.dispatchEvent(new CustomEvent(name, { detail }));
}

export function on(name, fn) {
  bus.addEventListener(name, (e) => fn(e.detail));
}

export function select(id) {
  if (state.selected === id) return;
  state.selected = id;
  history.replaceState(null, "", id ? `#image=${encodeURIComponent(id)}` : location.pathname);
  emit("select", id);
}

export const signName = (id) => (id === "none" ? "no sign" : state.library.find((s) => s.id === id)?.name ?? id);
