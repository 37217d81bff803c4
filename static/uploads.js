// Upload queues: one request per file, so each file gets its own progress bar, a few at a time.
// Used by the image gallery and the camera calibration.

import { upload } from "./api.js";
import { el, plural, toast } from "./ui.js";

const PARALLEL_UPLOADS = 3;
// For files the browser gives no media type: what the server reads (pipeline/image.py).
const IMAGE_FILE = /\.(jpe?g|png|bmp|tiff?|webp|gif|pgm|ppm)$/i;

/** What a queue sends by default: images, counted as such. `accepts(file)`, and the message for a file refused. */
export const IMAGES = {
  noun: "image",
  accepts: (file) => file.type.startsWith("image/") || IMAGE_FILE.test(file.name),
  refusal: (file) => `${file.name}: not an image file (use JPEG, PNG, TIFF, WebP, BMP or GIF), skipped`,
};

let unfinished = 0;   // files queued or being sent, in every queue: leaving the page drops them

window.addEventListener("beforeunload", (e) => {
  if (unfinished) e.preventDefault();   // the browser asks whether to leave the page all the same
});

function uploadRow(list, file) {
  const bar = el("div.bar");
  const status = el("span.upload-status", {}, "queued");
  const row = el("li.upload", {}, el("span.upload-name", { title: file.name }, file.name),
    el("div.progress", {}, bar), status,
    el("button.icon", { type: "button", title: "Dismiss", onclick: () => row.remove() }, "×"));
  list.append(row);
  return {
    progress(p) {
      bar.style.width = `${Math.round(p * 100)}%`;
      status.textContent = p < 1 ? `${Math.round(p * 100)}%` : "checking…";
    },
    done(message) {
      row.classList.add("ok");
      status.textContent = message;
      setTimeout(() => row.remove(), 3000);
    },
    stop() {
      status.textContent = "stopped";
      setTimeout(() => row.remove(), 3000);
    },
    fail(message) {
      row.classList.add("failed");
      status.textContent = message;
    },
  };
}

/** The line over a queue's progress rows counting the files sent since it was last idle: how many
 *  the server has stored, how many failed or were stopped and how many are still to go. Shown for
 *  two files or more; it goes a while after the last, and stays while any failed. */
function batchLine(list, noun) {
  const text = el("span.upload-status");
  const line = el("li.upload.batch", { role: "status" }, text,
    el("button.icon", { type: "button", title: "Dismiss", onclick: () => line.remove() }, "×"));
  let counts = null;   // {total, stored, failed, stopped} of the batch being sent
  let removal = null;
  const render = () => {
    const { total, stored, failed, stopped } = counts, left = total - stored - failed - stopped;
    text.textContent = [`${stored} of ${plural(total, noun)} stored`, failed && `${failed} failed`,
      stopped && `${stopped} stopped`, left && `${left} to go`].filter(Boolean).join(" · ");
    line.hidden = total < 2;
  };
  return {
    add(n) {
      if (!counts) {
        clearTimeout(removal);
        counts = { total: 0, stored: 0, failed: 0, stopped: 0 };
        line.className = "upload batch";
        list.prepend(line);
      }
      counts.total += n;
      render();
    },
    count(outcome, n = 1) {
      counts[outcome] += n;
      render();
    },
    end() {
      line.classList.add(counts.failed ? "failed" : "ok");
      if (line.hidden) line.remove();
      else if (!counts.failed) removal = setTimeout(() => line.remove(), 6000);
      counts = null;
    },
  };
}

/** A multipart form with `file` as the field "files" (what the upload routes take) and `fields`. */
export function filesForm(file, fields = {}) {
  const form = new FormData();
  form.append("files", file);
  for (const [name, value] of Object.entries(fields)) form.append(name, value);
  return form;
}

/**
 * A queue that POSTs each image file to `url` as the multipart form `form(file)` (built when the
 * file is queued, so it keeps the choices made then), with a progress row in `list`. Each form
 * also names the batch (the files queued until the queue is next idle) and the file's position
 * in it: the server lists them in that order, whichever of the parallel uploads lands first.
 * `done(body)` gets each JSON answer and returns the row's closing message; `idle()` runs when
 * the queue has emptied. `kind`: the files it takes (IMAGES by default; others are refused with a
 * message). Returns `enqueue(files)`, with `enqueue.left()` the files queued or being sent and
 * `enqueue.stop()` (see there). `ordered` false: a route that lists what it gets as it lands (flights)
 * is sent no batch or position, which it would refuse as fields it does not take.
 */
export function uploadQueue({ list, url, form, done, idle = () => {}, kind = IMAGES, ordered = true }) {
  const queue = [];
  const batch = batchLine(list, kind.noun);
  let active = 0;
  let batchName = "", position = 0;
  const waiting = [];   // resolves of stop()s waiting for the files being sent

  async function send({ body, row }) {
    try {
      row.done(done(await upload(url, body, row.progress)));
      batch.count("stored");
    } catch (err) {
      row.fail(err.message);
      batch.count("failed");
    }
  }

  function pump() {
    while (active < PARALLEL_UPLOADS && queue.length) {
      active += 1;
      send(queue.shift()).finally(() => {
        active -= 1;
        unfinished -= 1;
        pump();
        if (!active && !queue.length) {
          batch.end();
          idle();
          waiting.splice(0).forEach((resolve) => resolve());
        }
      });
    }
  }

  function enqueue(files) {
    const images = [...files].filter((file) => {
      const accepted = kind.accepts(file);
      if (!accepted) toast(kind.refusal(file), "error");
      return accepted;
    });
    if (!images.length) return;
    if (!active && !queue.length) {
      batchName = Math.random().toString(36).slice(2);
      position = 0;
    }
    batch.add(images.length);
    unfinished += images.length;
    for (const file of images) {
      const body = form(file);
      if (ordered) {
        body.append("batch", batchName);
        body.append("position", position++);
      }
      queue.push({ body, row: uploadRow(list, file) });
    }
    pump();
  }

  enqueue.left = () => queue.length + active;

  /** Drop the files not sent yet. Resolves once those being sent have their answers: the server
   *  may store them whatever the page does now, so a caller clearing up waits for them. */
  enqueue.stop = () => {
    const dropped = queue.splice(0);
    dropped.forEach(({ row }) => row.stop());
    unfinished -= dropped.length;
    if (dropped.length) batch.count("stopped", dropped.length);
    return active ? new Promise((resolve) => waiting.push(resolve)) : Promise.resolve();
  };

  return enqueue;
}

/** Make `zone` a drop target for files, shown with the class "dragging" while files are over it. */
export function dropTarget(zone, onFiles) {
  let depth = 0;
  // Stopped here: a drop zone inside another (a dialog over the page) must not feed both.
  const handle = (e) => { e.preventDefault(); e.stopPropagation(); };
  zone.addEventListener("dragenter", (e) => { handle(e); depth += 1; zone.classList.add("dragging"); });
  zone.addEventListener("dragleave", (e) => {
    handle(e);
    depth -= 1;
    if (depth <= 0) { depth = 0; zone.classList.remove("dragging"); }
  });
  zone.addEventListener("dragover", handle);
  zone.addEventListener("drop", (e) => {
    handle(e);
    depth = 0;
    zone.classList.remove("dragging");
    onFiles(e.dataTransfer.files);
  });
}
