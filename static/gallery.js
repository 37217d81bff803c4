// Image uploads (with a progress bar per file) and the image gallery.

import { api, latestGet } from "./api.js";
import { state, emit, on, select, signName } from "./store.js";
import { $, el, fill, plural, report, throttle, toast } from "./ui.js";
import { addFlights, isFlightFile } from "./flights.js";
import { dropTarget, filesForm, uploadQueue } from "./uploads.js";

/** ImageSummary.status as the page words it, and what it means. "no sign" alone would read as the
 *  expected label of that name, so the statuses of unlabelled images say they are unlabelled. */
export const STATUS = {
  correct: { text: "correct", title: "labelled: the result is the expected sign, or no sign where none was expected" },
  wrong: { text: "wrong", title: "labelled: the result is not the expected label" },
  recognized: { text: "recognised (unlabelled)", title: "no expected label: a sign was recognised" },
  none: { text: "no sign (unlabelled)", title: "no expected label: no sign was found" },
  pending: { text: "pending", title: "no result yet for the current settings, camera and library" },
  error: { text: "error", title: "the image could not be run: the camera does not fit it, or the pipeline failed "
    + "(its card says why)" },
};
const STATUSES = Object.keys(STATUS);

/** Word `badge` for ImageSummary.status `status`, with what it means as its tooltip. */
export function showStatus(badge, status) {
  badge.textContent = STATUS[status].text;
  badge.title = STATUS[status].title;
}

let enqueue = null;   // the gallery's upload queue

function bindUpload() {
  enqueue = uploadQueue({
    list: $("#uploads"),
    url: "/api/images",
    form: (file) => filesForm(file, { expected: $("#expected").value }),
    done: () => {
      refreshImages();
      // Recognition runs in the background; the card shows its result when it lands.
      return "✓ added";
    },
  });
  const picker = $("#file-picker");
  picker.onchange = () => { enqueue(picker.files); picker.value = ""; };
  // The whole page is a drop target: aiming at a small box is needless friction. Videos and bags are flights.
  dropTarget(document.body, (files) => {
    const all = [...files];
    const flights = all.filter(isFlightFile);
    if (flights.length) addFlights(flights);
    if (flights.length < all.length) enqueue(all.filter((file) => !isFlightFile(file)));
  });
}

/** Options for an expected-label select: unlabelled, "none" (no sign in the photo) or a library sign. */
export function fillExpected(select, value = select.value) {
  fill(select, el("option", { value: "" }, "unlabelled"), el("option", { value: "none" }, "no sign"),
    ...state.library.map((s) => el("option", { value: s.id }, s.name)));
  select.value = value === "none" || state.library.some((s) => s.id === value) ? value : "";
}

// ---- gallery

const cards = new Map();   // id -> {card, parts}
// style.css's one column (phones): the page scrolls, not the panels, and the detail is under every card.
const ONE_COLUMN = window.matchMedia("(max-width: 760px)");
let bringing = null;   // the image chosen in one column, whose detail is to be brought into view

/** Show image `id` (null: none) as the person chose it: its card, ← →, ‹ ›, a #image= link; not an
 *  image opened for them. In one column the detail view lies under the whole gallery, out of sight
 *  (929 px down on a 390×844 phone), and a choice seemed to do nothing: the page scrolls to the
 *  detail once it shows the image (scrolled to before, the new image's detail drawn over the old one
 *  left its top off the screen). Wider, the detail is read beside or under the gallery in its own
 *  panel and only the gallery scrolls (`reveal`). */
export function choose(id) {
  const detail = $("#detail"), shown = !detail.hidden && detail.dataset.id === id;
  bringing = ONE_COLUMN.matches ? id : null;
  select(id);
  if (shown) bringDetail(id);   // nothing is drawn again
}

function bringDetail(id) {
  if (id !== bringing) return;
  bringing = null;
  $("#detail").scrollIntoView();
}

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
    onclick: () => choose(img.id),
    onkeydown: (e) => { if (e.key === "Enter" || e.key === " ") { e.preventDefault(); choose(img.id); } },
  }, el("div.thumb-box", {}, parts.thumb, parts.badge), parts.name, parts.label, parts.stats, remove);
  return { card, parts };
}

function updateCard({ card, parts }, img) {
  for (const s of STATUSES) card.classList.toggle(`status-${s}`, img.status === s);
  card.classList.toggle("selected", img.id === state.selected);
  card.dataset.status = img.status;
  card.dataset.version = img.settings_version;
  showStatus(parts.badge, img.status);
  parts.name.textContent = img.name;
  parts.name.title = img.name;
  parts.label.textContent = img.error ? "could not run" : img.label ? signName(img.label) : "no sign";
  parts.label.title = img.error || (img.expected ? `expected: ${signName(img.expected)}` : "no expected label");
  // A failed run measured nothing: its zero inliers and margin would read as a result. The plaque
  // fallback matches no features: its correlation with the sign decided, not inliers.
  const decided = img.by_plaque ? [
    el("span", { title: "recognised by the plaque fallback: the plaque's correlation with the sign (no feature "
      + "inliers)" }, `plaque ${img.plaque_correlation.toFixed(2)}`),
  ] : [
    el("span", { title: "RANSAC inliers of the best sign" }, `${img.inliers ?? "–"} inl`),
    el("span", { title: "inlier margin over the runner-up" }, `Δ ${img.margin ?? "–"}`),
  ];
  fill(parts.stats, img.error ? null : [
    ...decided, img.status === "wrong" ? el("span.expected", {}, `≠ ${signName(img.expected)}`) : null]);
}

function renderGallery() {
  const gallery = $("#gallery");
  const seen = new Set();
  for (const img of state.images) {
    seen.add(img.id);
    if (!cards.has(img.id)) cards.set(img.id, makeCard(img));
    const entry = cards.get(img.id);
    updateCard(entry, img);
    gallery.append(entry.card);   // re-appending keeps the server's order without rebuilding
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
    el("span.count", {}, plural(state.images.length, "image")),
    labelled ? el("span.count.accuracy", {
      title: "correct / labelled images with a result for the current state (pending and failed ones left out)",
    }, `${counts.correct}/${labelled} correct`) : null,
    // "correct" is already in the accuracy figure.
    ...STATUSES.filter((s) => counts[s] && !(s === "correct" && labelled)).map((s) =>
      el(`span.count.status-${s}`, { title: STATUS[s].title }, el("i.dot"), `${counts[s]} ${STATUS[s].text}`)));
}

const getImages = latestGet("/api/images");   // refreshes 250 ms apart can cross

/** The server's images, shown unless a newer list was asked for meanwhile. */
async function loadImages() {
  const { body, newest } = await getImages();
  if (newest) {
    state.images = body.images;
    emit("images", state.images);
  }
  return body.images;
}

export const refreshImages = throttle(() => loadImages().catch(report), 250);

/** Remove every image, stopping the uploads still to go first: files still queued kept uploading
 *  after a remove-all and were left in the gallery. */
async function removeAll() {
  const button = $("#clear-images");
  const images = state.images.length, uploads = enqueue.left();
  const what = [images && `all ${plural(images, "image")}`, uploads && `the ${plural(uploads, "upload")} still to go`]
    .filter(Boolean).join(" and ");
  if (!what || !confirm(`Remove ${what}?`)) return;
  const label = button.textContent;
  button.disabled = true;
  button.textContent = "removing…";
  try {
    await enqueue.stop();   // the ones being sent land first, so the delete takes them too
    const { removed } = await api("DELETE", "/api/images");
    const left = (await loadImages()).length;   // uploaded from elsewhere after the delete
    const kept = left ? `; ${left} added since ${left === 1 ? "is" : "are"} still there` : "";
    toast(`removed ${plural(removed, "image")}${kept}`, left ? "warn" : "info");
  } catch (err) {
    report(err);
    refreshImages();
  } finally {
    button.disabled = false;
    button.textContent = label;
  }
}

/** Scroll the gallery, and only it, so that `card` shows whole in it. scrollIntoView also scrolled
 *  the images panel and the page: stepping to the next image (→) took the detail view being read,
 *  below the gallery in a low window, out of sight. */
function reveal(card) {
  const gallery = $("#gallery");
  const box = gallery.getBoundingClientRect(), at = card.getBoundingClientRect();
  const pad = parseFloat(getComputedStyle(gallery).paddingTop);
  if (at.top < box.top + pad) gallery.scrollTop -= box.top + pad - at.top;
  else if (at.bottom > box.bottom - pad) gallery.scrollTop += Math.min(at.bottom - box.bottom + pad, at.top - box.top - pad);
}

export function initGallery() {
  bindUpload();
  fillExpected($("#expected"));
  on("library", () => fillExpected($("#expected")));
  on("images", renderGallery);
  on("detail", bringDetail);
  on("select", () => {
    for (const [id, { card }] of cards) card.classList.toggle("selected", id === state.selected);
    const card = cards.get(state.selected)?.card;
    if (card) reveal(card);
  });
  $("#clear-images").onclick = removeAll;
}
