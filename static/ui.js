// DOM and notification helpers shared by every module.

/** Create an element: el("div.card.wide", {title: "x", onclick}, child, "text", ...). */
export function el(spec, attrs = {}, ...children) {
  const [tag, ...classes] = spec.split(".");
  const node = document.createElement(tag || "div");
  if (classes.length) node.className = classes.join(" ");
  for (const [key, value] of Object.entries(attrs)) {
    if (value === undefined || value === null || value === false) continue;
    if (key.startsWith("on")) node.addEventListener(key.slice(2), value);
    else if (key === "dataset") Object.assign(node.dataset, value);
    else if (key in node && typeof value !== "string") node[key] = value;
    else node.setAttribute(key, value === true ? "" : value);
  }
  node.append(...present(children));
  return node;
}

const present = (children) => children.flat().filter((c) => c !== null && c !== undefined && c !== false);

/** Replace a node's children, skipping null/false ones like `el` does (for conditional parts). */
export function fill(node, ...children) {
  node.replaceChildren(...present(children));
}

export const $ = (selector, root = document) => root.querySelector(selector);

/** Show a message, `kind` "error", "warn" or "info"; errors and warnings stay until dismissed so
 *  none goes unseen. */
export function toast(message, kind = "error") {
  const box = el(`div.toast.${kind}`, { role: kind === "info" ? "status" : "alert" },
    el("span.toast-msg", {}, message),
    el("button.icon", { type: "button", title: "Dismiss", onclick: () => box.remove() }, "×"));
  $("#toasts").append(box);
  if (kind === "info") setTimeout(() => box.remove(), 4000);
  return box;
}

/** Open `dialog` as a modal one, taking the toasts along until it closes: a modal dialog is drawn
 *  over the whole page (the top layer) and makes the rest of it inert, so a toast left outside would
 *  be hidden under it and could not be dismissed. */
export function showModal(dialog) {
  if (dialog.open) return;
  const toasts = $("#toasts"), home = toasts.parentElement;
  dialog.showModal();
  dialog.append(toasts);
  dialog.addEventListener("close", () => home.append(toasts), { once: true });
}

export function report(err) {
  console.error(err);
  toast(err?.message || String(err), "error");
}

/** Call `fn` once `ms` after the last call (with its arguments); `.flush()` makes that call at
 *  once, if one is pending. */
export function debounce(fn, ms) {
  let timer = null, latest = [];
  const debounced = (...args) => {
    clearTimeout(timer);
    latest = args;
    timer = setTimeout(debounced.flush, ms);
  };
  debounced.flush = () => {
    if (timer === null) return;
    clearTimeout(timer);
    timer = null;
    fn(...latest);
  };
  return debounced;
}

/** Run `fn` at most once per `ms`, always including a trailing call so the last state is shown. */
export function throttle(fn, ms) {
  let last = 0, timer = null;
  return () => {
    const wait = last + ms - Date.now();
    if (timer) return;
    if (wait <= 0) { last = Date.now(); fn(); return; }
    timer = setTimeout(() => { timer = null; last = Date.now(); fn(); }, wait);
  };
}

export const fmt = (value, digits = 2) =>
  value === null || value === undefined || Number.isNaN(value) ? "–" : Number(value).toFixed(digits);

/** "1 photo", "2 photos". */
export const plural = (n, noun) => `${n} ${noun}${n === 1 ? "" : "s"}`;

export function download(url) {
  el("a", { href: url, download: "" }).click();
}
