// Upload queue (one request per file, so each gets its own progress bar) and the image gallery.

import { api, get, upload } from "./api.js";
import { state, emit, on, select, signName } from "./store.js";
import { $, el, fill, report, throttle, toast } from "./ui.js";

const PARALLEL_UPLOADS = 3;
const IMAGE_FILE = /\.(jpe?g|png|bmp|tiff?|webp|pgm|ppm)$/i;
const STATUSES = ["correct", "wrong", "recognized", "none", "pending", "error"];

const queue = [];
let active = 0;

function uploadRow(file) {
  const bar = el("div.bar");
  const status = el("span.upload-status", {}, "queued");
  const row = el("li.upload", {}, el("span.upload-name", { title: file.name }, file.name),
    el("div.progress", {}, bar), status,
    el("button.icon", { type: "button", title: "Dismiss", onclick: () => row.remove() }, "×"));
  $("#uploads").append(row);
  return {
    progress(p) {
      bar.style.width = `${Math.round(p * 100)}%`;
      status.textContent = p < 1 ? `${Math.round(p * 100)}%` : "checking…";
    },
    done() {
      row.classList.add("ok");
      // Recognition runs in the background; the card shows its result when it lands.
      status.textContent = "✓ added";
      setTimeout(() => row.remove(), 3000);
    },
    fail(message) {
      row.classList.add("failed");
      status.textContent = message;
      status.title = message;
    },
  };
}

async function send({ file, expected, row }) {
  const form = new FormData();
  form.append("files", file);
  form.append("expected", expected);
  try {
    await upload("/api/images", form, row.progress);
    row.done();
    refreshImages();
  } catch (err) {
    row.fail(err.message);
  }
}

function pump() {
  while (active < PARALLEL_UPLOADS && queue.length) {
    active += 1;
    send(queue.shift()).finally(() => { active -= 1; pump(); });
  }
}

function enqueue(files) {
  const expected = $("#expected").value;
  for (const file of files) {
    if (!file.type.startsWith("image/") && !IMAGE_FILE.test(file.name)) {
      toast(`${file.name}: not an image file, skipped`, "error");
      continue;
    }
    queue.push({ file, expected, row: uploadRow(file) });
  }
  pump();
}

function bindUpload() {
  const picker = $("#file-picker");
  picker.onchange = () => { enqueue(picker.files); picker.value = ""; };
  // The whole page is a drop target: aiming at a small box is needless friction.
  let depth = 0;
  const zone = document.body;
  zone.addEventListener("dragenter", (e) => { e.preventDefault(); depth += 1; zone.classList.add("dragging"); });
  zone.addEventListener("dragleave", () => { depth -= 1; if (depth <= 0) { depth = 0; zone.classList.remove("dragging"); } });
  zone.addEventListener("dragover", (e) => e.preventDefault());
  zone.addEventListener("drop", (e) => {
    e.preventDefault();
    depth = 0;
    zone.classList.remove("dragging");
    enqueue(e.dataTransfer.files);
  });
}

/** Options for an expected-label select: unlabelled, "none" (no sign in the photo) or a library sign. */
export function fillExpected(select, value = select.value) {
  fill(select, el("option", { value: "" }, "unknown"), el("option", { value: "none" }, "no sign"),
    ...state.library.map((s) => el("option", { value: s.id }, s.name)));
  select.value = value === "none" || state.library.some((s) => s.id === value) ? value : "";
}

// ---- gallery

const cards = new Map();   // id -> {card, parts}

function makeCard(img) {
  const parts = {
    thumb: el("img.thumb", { src: `/api/images/${img.id}/file`, alt: "", loading: "lazy", decoding: "async" }),
    badge: el("span.badge"),
    name: el("div.card-name"),
    label: el("div.card-label"),
    stats: el("div.card-stats"),
  };
  const remove = el("button.icon.remove", {
    type: "button", title: "Remove this image",
    onclick: async (e) => {
      e.stopPropagation();
      try { await api("DELETE", `/api/images/${img.id}`); } catch (err) { report(err); }
      refreshImages();
    },
  }, "×");
  const card = el("div.card", {
    tabIndex: 0, role: "button", dataset: { id: img.id },
    onclick: () => select(img.id),
    onkeydown: (e) => { if (e.key === "Enter" || e.key === " ") { e.preventDefault(); select(img.id); } },
  }, el("div.thumb-box", {}, parts.thumb, parts.badge), parts.name, parts.label, parts.stats, remove);
  return { card, parts };
}

function updateCard({ card, parts }, img) {
  for (const s of STATUSES) card.classList.toggle(`status-${s}`, img.status === s);
  card.classList.toggle("selected", img.id === state.selected);
  card.dataset.status = img.status;
  card.dataset.version = img.settings_version;
  parts.badge.textContent = img.status;
  parts.name.textContent = img.name;
  parts.name.title = img.name;
  const label = img.label ? signName(img.label) : img.status === "error" ? "error" : "no sign";
  parts.label.textContent = label;
  parts.label.title = img.error || (img.expected ? `expected: ${signName(img.expected)}` : "no expected label");
  fill(parts.stats,
    el("span", { title: "RANSAC inliers of the best sign" }, `${img.inliers ?? "–"} inl`),
    el("span", { title: "inlier margin over the runner-up" }, `Δ ${img.margin ?? "–"}`),
    img.status === "wrong" ? el("span.expected", {}, `≠ ${signName(img.expected)}`) : null);
}

function renderGallery() {
  const gallery = $("#gallery");
  const seen = new Set();
  for (const img of state.images) {
    seen.add(img.id);
    if (!cards.has(img.id)) cards.set(img.id, makeCard(img));
    const entry = cards.get(img.id);
    updateCard(entry, img);
    gallery.append(entry.card);   // re-appending keeps upload order without rebuilding
  }
  for (const [id, entry] of cards) {
    if (!seen.has(id)) { entry.card.remove(); cards.delete(id); }
  }
  $("#gallery-empty").hidden = state.images.length > 0;
  renderCounts();
}

function renderCounts() {
  const counts = Object.fromEntries(STATUSES.map((s) => [s, 0]));
  for (const img of state.images) counts[img.status] = (counts[img.status] || 0) + 1;
  const labelled = counts.correct + counts.wrong;
  fill($("#counts"),
    el("span.count", {}, `${state.images.length} images`),
    labelled ? el("span.count.accuracy", { title: "correct / images with an expected label" },
      `${counts.correct}/${labelled} correct`) : null,
    // "correct" is already in the accuracy figure.
    ...STATUSES.filter((s) => counts[s] && !(s === "correct" && labelled)).map((s) =>
      el(`span.count.status-${s}`, { title: s }, el("i.dot"), `${counts[s]} ${s}`)));
}

export const refreshImages = throttle(async () => {
  try {
    const body = await get("/api/images");
    state.images = body.images;
    emit("images", state.images);
  } catch (err) {
    report(err);
  }
}, 250);

export function initGallery() {
  bindUpload();
  fillExpected($("#expected"));
  on("library", () => fillExpected($("#expected")));
  on("images", renderGallery);
  on("select", () => {
    for (const [id, { card }] of cards) card.classList.toggle("selected", id === state.selected);
    cards.get(state.selected)?.card.scrollIntoView({ block: "nearest" });
  });
  $("#clear-images").onclick = async () => {
    if (!state.images.length || !confirm(`Remove all ${state.images.length} images?`)) return;
    for (const img of state.images) {
      try { await api("DELETE", `/api/images/${img.id}`); } catch (err) { report(err); }
    }
    refreshImages();
  };
}
