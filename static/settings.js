// Settings form generated from /api/settings/schema, kept in sync with the server (and through
// it with the viser sliders): local edits are PUT debounced; server `settings` events update the
// controls, which fires no input events, so nothing is echoed back.

import { api, get } from "./api.js";
import { state, emit } from "./store.js";
import { $, el, fill, debounce, download, report, toast } from "./ui.js";

const controls = new Map();   // name -> {entry, row, read(), write(value)}
let pending = {};             // edits not yet sent
// name -> PUTs sent but not yet answered. A count, not a flag: an earlier PUT answering while a
// later one is on its way must not let server events put the earlier value back in the control.
const inflight = new Map();
let dragging = null;          // the slider under the pointer: server updates must not yank it

const decimals = (x) => (String(x).split(".")[1] || "").length;

/** The smallest change of the setting `entry`. */
export const stepOf = (entry) => entry.step || (entry.type === "int" ? 1 : 0.001);

function snap(value, entry) {
  const step = stepOf(entry);
  const v = Math.min(entry.max, Math.max(entry.min, Math.round(value / step) * step));
  return Number(v.toFixed(decimals(step)));
}

/** Slider position <-> value. Wide positive ranges (iterations, feature counts) get a log scale
 *  so small values stay reachable; ranges too wide even for that (seed) get no slider. */
function sliderScale(entry) {
  const { min, max, step } = entry;
  if ((max - min) / (step || 1) <= 2000) {
    return { min, max, step: step || "any", toPos: (v) => v, toValue: (p) => snap(Number(p), entry) };
  }
  if (min <= 0 || max / min > 1e6) return null;
  const k = Math.log(max / min);
  return {
    min: 0, max: 1000, step: 1,
    toPos: (v) => Math.round((1000 * Math.log(v / min)) / k),
    toValue: (p) => snap(min * Math.exp((Number(p) / 1000) * k), entry),
  };
}

function numericControl(entry, id, change) {
  const num = el("input.num", { id, type: "number", min: entry.min, max: entry.max, step: entry.step || "any" });
  const scale = sliderScale(entry);
  const range = scale && el("input.range", {
    type: "range", min: scale.min, max: scale.max, step: scale.step, tabIndex: -1, "aria-label": entry.name,
  });
  const enabled = entry.nullable && el("input.toggle", { type: "checkbox", title: "off = null (not used)" });
  const write = (value) => {
    const off = value === null || value === undefined;
    if (enabled) enabled.checked = !off;
    num.disabled = off;
    if (range) range.disabled = off;
    if (off) return;
    num.value = value;
    if (range) range.value = scale.toPos(value);
  };
  // As typed, not clamped to the range nor rounded to the step: the server says what it refuses
  // and why, and the form then shows the value it kept (push).
  const read = () => (enabled && !enabled.checked ? null : Number(num.value));
  // Typed but not yet applied (Enter or leaving the field applies it): server updates must not
  // overwrite it. A field merely holding the cursor is not typing: it follows other tabs.
  let typing = false;
  num.addEventListener("input", () => { typing = true; });
  num.addEventListener("focusout", () => {
    typing = false;
    // Left unchanged after typing (no change event): show the value in use again.
    if (!held(entry.name)) write(state.settings[entry.name]);
  });
  num.addEventListener("change", () => {
    typing = false;
    // Left empty (or holding no number): nothing to send, so show the server's value again.
    if (num.value === "") {
      write(state.settings[entry.name]);
      return;
    }
    if (range) range.value = scale.toPos(read());
    change();
  });
  if (range) {
    range.addEventListener("input", () => { num.value = scale.toValue(range.value); change(); });
    range.addEventListener("pointerdown", () => { dragging = entry.name; });
  }
  if (enabled) {
    enabled.addEventListener("change", () => {
      // Re-enabling starts from the top of the range, the least restrictive upper gate.
      if (enabled.checked && num.value === "") num.value = entry.max;
      write(read());
      change();
    });
  }
  return { head: [enabled, num].filter(Boolean), body: range, read, write, typing: () => typing };
}

// Released anywhere, not only over the slider it started on.
window.addEventListener("pointerup", () => { dragging = null; });

function choiceControl(entry, id, change) {
  const select = el("select", { id, onchange: change }, entry.choices.map((c) => el("option", { value: c }, c)));
  return { head: [select], read: () => select.value, write: (v) => { select.value = v; } };
}

function boolControl(entry, id, change) {
  const box = el("input.toggle", { id, type: "checkbox", onchange: change });
  return { head: [box], read: () => box.checked, write: (v) => { box.checked = Boolean(v); } };
}

const builders = { float: numericControl, int: numericControl, choice: choiceControl, bool: boolControl };

function buildField(entry) {
  const id = `set-${entry.name}`;
  const change = () => edit(entry.name);
  const control = builders[entry.type](entry, id, change);
  const reset = el("button.icon.reset", {
    type: "button", title: `Reset to default (${entry.default ?? "null"})`,
    onclick: () => { control.write(entry.default); change(); },
  }, "↺");
  const row = el("div.field", { title: entry.help, dataset: { name: entry.name, type: entry.type } },
    el("div.field-head", {}, el("label", { for: id }, entry.name), reset, ...control.head),
    control.body);
  controls.set(entry.name, { entry, row, ...control });
  return row;
}

function buildForm() {
  const groups = Map.groupBy(state.schema, (e) => e.group);
  // Fields apply as they change; Enter must not submit (and reload) the page. Not an inline
  // onsubmit: the Content-Security-Policy allows no inline script.
  $("#settings-form").addEventListener("submit", (event) => event.preventDefault());
  fill($("#settings-form"), ...[...groups].map(([group, entries]) =>
    el("details.group", { open: true },
      el("summary", {}, group, el("span.group-count", {})),
      entries.map(buildField))));
}

function edit(name) {
  const c = controls.get(name);
  pending[name] = c.read();
  markChanged(name, pending[name]);
  push();
}

const push = debounce(async () => {
  const changes = pending;
  pending = {};
  const names = Object.keys(changes);
  names.forEach((n) => inflight.set(n, (inflight.get(n) ?? 0) + 1));
  try {
    // keepalive: sent in full even when the page is closed or reloaded meanwhile (see initSettings).
    apply(await api("PUT", "/api/settings", changes, { keepalive: true }));
  } catch (err) {
    // The server kept its settings: show them again instead of the rejected values, and say so.
    const read = await get("/api/settings").catch(() => null);
    // Read before a later change of this page's landed, it would put that change's controls back.
    const kept = read && read.version < state.version ? { version: state.version, settings: state.settings } : read;
    apply(kept, true);
    report(kept ? new Error(`${err.message}; the server keeps ${names.map((n) => `${n} ${kept.settings[n] ?? "off"}`)
      .join(", ")}`) : err);
  } finally {
    for (const n of names) {
      if (inflight.get(n) > 1) inflight.set(n, inflight.get(n) - 1);
      else inflight.delete(n);
    }
  }
}, 150);

function markChanged(name, value) {
  const c = controls.get(name);
  c.row.classList.toggle("changed", value !== c.entry.default);
}

/** Whether setting `name`'s control holds a value of the person's that server updates must not
 *  overwrite: an edit not yet sent or answered, a slider being dragged, a number being typed. */
function held(name) {
  return name in pending || inflight.has(name) || dragging === name || Boolean(controls.get(name).typing?.());
}

/** Show server settings `{version, settings}`; `force` also overwrites controls with local edits. */
export function apply(payload, force = false) {
  if (!payload) return;
  const settings = payload.settings ?? payload;
  if (payload.version !== undefined && payload.version < state.version && !force) return;
  state.settings = settings;
  if (payload.version !== undefined) state.version = payload.version;
  for (const [name, c] of controls) {
    if (!(name in settings)) continue;
    if (held(name) && !force) continue;
    c.write(settings[name]);
    markChanged(name, settings[name]);
  }
  for (const group of document.querySelectorAll("#settings-form details")) {
    const n = group.querySelectorAll(".field.changed").length;
    group.querySelector(".group-count").textContent = n ? `${n} changed` : "";
  }
  for (const button of document.querySelectorAll("#presets button")) {
    const p = state.presets[button.value];
    button.classList.toggle("active", Boolean(p) && Object.entries(p).every(([k, v]) => settings[k] === v));
  }
  $("#settings-version").textContent = `settings v${state.version}`;
  emit("settings", settings);
}

/** The setting `name`'s `value` as its field shows it, with at least its step's decimals: a
 *  threshold of 0.755 (step 0.01) reads 0.755, not 0.76, and 0.8 reads 0.80. */
export function settingText(name, value) {
  return value.toFixed(Math.max(decimals(stepOf(controls.get(name).entry)), decimals(value)));
}

/** The setting `name`'s value as its form control holds it, an edit not yet sent or answered
 *  included: a key pressed again before the server has answered steps on from it. */
export const settingValue = (name) => controls.get(name).read();

/** Change settings from elsewhere on the page (calibration, sweep): same path as a form edit. */
export function setSetting(name, value) {
  const c = controls.get(name);
  c.write(typeof value === "number" ? snap(value, c.entry) : value);
  edit(name);
}

async function postAndApply(url, body, message) {
  try {
    apply(await api("POST", url, body));
    toast(message, "info");
  } catch (err) {
    report(err);
  }
}

function buildToolbar() {
  fill($("#presets"), ...Object.keys(state.presets).map((name) =>
    el("button", { type: "button", value: name, title: `Apply the ${name} preset`,
      onclick: () => postAndApply(`/api/settings/preset/${encodeURIComponent(name)}`, undefined,
        `preset ${name} applied`) }, name)));
  $("#export-settings").onclick = () => download("/api/settings/export");
  const file = $("#import-settings");
  file.onchange = () => {
    const form = new FormData();
    form.append("file", file.files[0]);
    postAndApply("/api/settings/import", form, `imported ${file.files[0].name}`);
    file.value = "";
  };
}

export async function initSettings() {
  const [schema, current, presets] = await Promise.all([
    get("/api/settings/schema"), get("/api/settings"), get("/api/presets")]);
  state.schema = schema;
  state.presets = presets;
  buildForm();
  buildToolbar();
  apply(current, true);
  // An edit still waiting out the debounce when the page is closed or reloaded is sent now, not lost.
  window.addEventListener("pagehide", push.flush);
}
