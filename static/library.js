// The sign library (/api/library): its summary in the settings panel, and the Library dialog,
// which lists the signs (image, name, text, physical size), adds one from an image and removes one.

import { api, latestGet } from "./api.js";
import { emit, on, state } from "./store.js";
import { $, el, fill, plural, report, showModal, toast } from "./ui.js";
import { dropTarget } from "./uploads.js";

const SIGN_FIELDS = ["id", "name", "text", "width_m", "height_m", "kind"];   // POST /api/library's, besides `file`

let picked = null;   // {url, width, height} of the image chosen for a new sign
let idTyped = false; // the person typed the new sign's id: an image chosen after keeps it
const getLibrary = latestGet("/api/library");   // a sign added, then one removed: the lists can cross

export async function loadLibrary() {
  const { body, newest } = await getLibrary();
  if (!newest) return;
  state.library = body;
  emit("library", state.library);
}

/** Metres as typed in library.json: 0.6, 0.245. */
const metres = (value) => String(Number(value.toFixed(3)));

// The stored file's name changes when a sign is added again under its id: a new URL, not a cached image.
const imageUrl = (sign) => `/api/library/${encodeURIComponent(sign.id)}/image?v=${encodeURIComponent(sign.image)}`;

// ---- the list

async function removeSign(sign) {
  if (!confirm(`Remove the sign "${sign.name}" from the library? Every image is re-run without it.`)) return;
  try {
    await api("DELETE", `/api/library/${encodeURIComponent(sign.id)}`);
    toast(`sign ${sign.name} removed: every image is being re-run without it`, "info");
    await loadLibrary();
  } catch (err) {
    report(err);
  }
}

function signItem(sign, last) {
  return el("li.sign", { dataset: { id: sign.id } },
    el("img.sign-thumb", { src: imageUrl(sign), alt: sign.name, loading: "lazy" }),
    el("div", {},
      el("div.sign-name", {}, sign.name),
      sign.text && el("div.sign-text", { dir: "auto" }, sign.text),
      el("div.sign-meta", {}, el("span.mono", {}, sign.id),
        ` · ${metres(sign.width_m)} × ${metres(sign.height_m)} m · ${sign.kind}`)),
    el("button.icon.remove", {
      type: "button", disabled: last, "aria-label": `remove ${sign.name}`,
      title: last ? "The library's last sign cannot be removed: add another first" : `Remove ${sign.name} from the library`,
      onclick: () => removeSign(sign),
    }, "×"));
}

function renderLibrary() {
  const signs = state.library;
  fill($("#library-signs"), ...signs.map((sign) => signItem(sign, signs.length === 1)));
  $("#library-count").textContent = plural(signs.length, "sign");
  const info = $("#library-info");
  info.textContent = `${plural(signs.length, "sign")}: ${signs.map((s) => s.name).join(", ")}`;
  info.title = signs.map((s) => `${s.name} (${s.id}), ${metres(s.width_m)} × ${metres(s.height_m)} m`).join("\n");
}

// ---- adding one

/** A sign id from a file name: "Exit sign (2).png" -> "exit_sign_2"; a name without a-z or 0-9
 *  (مخرج.png) gives the first sign_<n> the library does not have, an id the server takes. */
function idFrom(fileName) {
  const id = fileName.replace(/\.[^.]*$/, "").toLowerCase().replace(/[^a-z0-9_-]+/g, "_")
    .replace(/^[_-]+|_+$/g, "").slice(0, 64);
  if (id) return id;
  const taken = new Set(state.library.map((s) => s.id));
  let n = 1;
  while (taken.has(`sign_${n}`)) n += 1;
  return `sign_${n}`;
}

/** The height the server will take from the width and the image's aspect, as the height's placeholder. */
function showHeightHint() {
  const width = Number($("#sign-width_m").value);
  $("#sign-height_m").placeholder = picked?.width && width > 0
    ? `${metres((width * picked.height) / picked.width)} from the image` : "from the image";
}

function showPicked() {
  const file = $("#sign-file").files[0];
  if (picked) URL.revokeObjectURL(picked.url);
  picked = file ? { url: URL.createObjectURL(file) } : null;
  $("#sign-file-name").textContent = file ? file.name : "none chosen, or drop one here";
  $("#sign-file-name").title = file?.name ?? "";
  const preview = $("#sign-preview");
  preview.hidden = !file;
  if (!file) { preview.removeAttribute("src"); showHeightHint(); return; }
  const shown = picked;
  preview.onload = () => {
    if (picked !== shown) return;
    Object.assign(picked, { width: preview.naturalWidth, height: preview.naturalHeight });
    showHeightHint();
  };
  preview.src = picked.url;
  // From each image chosen: after a wrong one, the right one's name, not the wrong one's.
  if (!idTyped) $("#sign-id").value = idFrom(file.name);
}

/** What the form lacks before it can be sent, null when nothing: said in a message, since the
 *  browser's own bubble for a required field was all a person saw, and easily missed. */
function missing() {
  if (!$("#sign-file").files.length) return "choose the sign's image first (or drop it on this dialog)";
  if (!$("#sign-id").value.trim()) return "give the sign an id: 1-64 of a-z, 0-9, _ and -";
  // A number field holds "" for what it cannot read ("0,6"): sent, a height would come from the image.
  for (const key of ["width_m", "height_m"]) {
    if ($(`#sign-${key}`).validity.badInput) return `the ${key.slice(0, -2)} is not a number: metres, e.g. 0.6`;
  }
  if (!$("#sign-width_m").value.trim()) return "give the sign's width in metres, measured on the wall";
  return null;
}

function signForm() {
  const form = new FormData();
  form.append("file", $("#sign-file").files[0]);
  for (const key of SIGN_FIELDS) form.append(key, $(`#sign-${key}`).value.trim());
  return form;
}

async function addSign(event) {
  event.preventDefault();
  const lacking = missing();
  if (lacking) { toast(lacking, "error"); return; }
  const button = $("#sign-add");
  button.disabled = true;
  const sent = $("#sign-file").files[0];
  try {
    const sign = await api("POST", "/api/library", signForm());
    toast(`sign ${sign.name} added: every image is being re-run with it`, "info");
    // A next sign's image chosen while this one was sent is kept, with what was typed for it.
    if ($("#sign-file").files[0] === sent) {
      $("#sign-form").reset();
      idTyped = false;
      showPicked();
    }
    await loadLibrary();
  } catch (err) {
    report(err);   // the server's reason: a bad id, a size, an image that does not fit its size, …
  } finally {
    button.disabled = false;
  }
}

function bindForm() {
  $("#sign-form").noValidate = true;   // `missing` says what is lacking, the server what is wrong
  $("#sign-form").addEventListener("submit", addSign);
  $("#sign-file").addEventListener("change", showPicked);
  $("#sign-id").addEventListener("input", (e) => { idTyped = e.target.value !== ""; });
  $("#sign-width_m").addEventListener("input", showHeightHint);
  // An image dropped on the dialog is the new sign's (not an image to recognise, as on the page).
  dropTarget($("#library-dialog"), (files) => {
    if (!files.length) return;
    const one = new DataTransfer();
    one.items.add(files[0]);
    $("#sign-file").files = one.files;
    showPicked();
  });
}

export function initLibrary() {
  const dialog = $("#library-dialog");
  $("#library-open").onclick = () => showModal(dialog);
  $("#library-close").onclick = () => dialog.close();
  bindForm();
  on("library", renderLibrary);
  renderLibrary();
}
