// The sign map (/api/map): its section in the settings panel. Build one from the photos and flights
// held (with an anchor sign, whose frame is the map's), load a map file, download it, clear it; a
// table of every mapped sign's position and 1-sigma. The 3D scene (server side) shows the map in a
// world of its own.

import { api, latestGet } from "./api.js";
import { on, signName, state } from "./store.js";
import { $, download, el, fill, fmt, plural, report, toast } from "./ui.js";

const getMap = latestGet("/api/map");   // a build, then a clear: the answers can cross
let held = null;   // MapOut, or null

/** A sign's 1-sigma for the table: fixed, else its worst direction's, position in mm over rotation in degrees. */
function sigmaCell(sign) {
  if (sign.fixed) return sign.fixed;
  if (sign.sigma_position_m === null) return "–";
  return [el("span.line", {}, `${fmt(1e3 * sign.sigma_position_m, 1)} mm`),
    el("span.line", {}, `${fmt(sign.sigma_rotation_deg, 2)}°`)];
}

function signRow(sign) {
  const seen = sign.images === null ? ""
    : `\nseen in ${plural(sign.images, "image")}${Object.keys(sign.seen_with || {}).length
      ? `, with ${Object.entries(sign.seen_with).map(([s, n]) => `${signName(s)} (${n})`).join(", ")}` : ""}`;
  return el("tr", { dataset: { id: sign.id }, title: `${sign.id}: position ${sign.position_m.map((v) => fmt(v, 4)).join(", ")} m, `
      + `yaw, pitch, roll ${sign.yaw_pitch_roll_deg.map((v) => fmt(v, 1)).join(", ")}°${seen}` },
    el("td.name", {}, signName(sign.id)),
    el("td.num.position", {}, sign.position_m.map((v) => fmt(v, 2)).join(" ")),
    el("td.num", {}, sigmaCell(sign)));
}

function renderMap() {
  const table = $("#map-signs");
  table.hidden = !held;
  $("#map-download").disabled = $("#map-clear").disabled = !held;
  if (!held) {
    fill(table);
    $("#map-info").textContent = "No sign map: build one from the photos and flights held, or load a map file.";
    fill($("#map-warnings"));
    return;
  }
  $("#map-info").textContent = `${plural(held.signs.length, "sign")} in frame ${held.frame}, ${held.source}. `
    + "1-sigma along the worst direction; the 3D scene's world (sign map) shows them.";
  fill(table, el("thead", {}, el("tr", {}, el("th", {}, "sign"), el("th.num", {}, "x y z (m)"), el("th.num", {}, "1σ"))),
    el("tbody", {}, held.signs.map(signRow)));
  fill($("#map-warnings"), [
    ...held.warnings,
    ...held.rejected.map((r) => `${r.image}: ${signName(r.sign)} rejected as inconsistent (chi-square ${fmt(r.chi2, 1)})`),
    ...Object.entries(held.unmapped).map(([s, why]) => `${signName(s)} not mapped: ${why}`),
  ].map((w) => el("li", {}, w)));
}

export async function loadMap() {
  const { body, newest } = await getMap();
  if (!newest) return;
  held = body;
  renderMap();
}

function renderAnchors() {
  const pick = $("#map-anchor");
  const chosen = pick.value;
  fill(pick, el("option", { value: "" }, "first seen"), state.library.map((s) => el("option", { value: s.id }, s.name)));
  pick.value = state.library.some((s) => s.id === chosen) ? chosen : "";
}

async function build() {
  const button = $("#map-build");
  button.disabled = true;
  button.textContent = "building…";
  try {
    const anchor = $("#map-anchor").value || null;
    held = await api("POST", "/api/map/build", { anchor });
    renderMap();
    toast(`sign map built: ${plural(held.signs.length, "sign")}, ${held.source}`, "info");
  } catch (err) {
    report(err);
  } finally {
    button.disabled = false;
    button.textContent = "build";
  }
}

export function initMap() {
  $("#map-build").onclick = build;
  const file = $("#map-file");
  file.onchange = async () => {
    const form = new FormData();
    form.append("file", file.files[0]);
    try {
      held = await api("PUT", "/api/map", form);
      renderMap();
      toast(`sign map ${held.source} loaded: ${plural(held.signs.length, "sign")}`, "info");
    } catch (err) {
      report(err);
    }
    file.value = "";
  };
  $("#map-download").onclick = () => download("/api/map/file");
  $("#map-clear").onclick = async () => {
    if (!confirm("Forget the sign map? Download it first to keep it.")) return;
    try {
      await api("DELETE", "/api/map");
      await loadMap();
    } catch (err) {
      report(err);
    }
  };
  on("library", () => { renderAnchors(); renderMap(); });
  on("map", () => loadMap().catch(report));
  renderAnchors();
  loadMap().catch(report);
}
