// Thin client for the signpose HTTP API (docs/web-contract.md). Every failure becomes an
// Error whose message is the server's `detail`, so callers can show it as is.

const UNREACHABLE = "cannot reach the signpose server: check that signpose serve is still running, then try again";

class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

/** The person-readable message in an error body: the server's `detail`, always a string. */
function detailOf(body, status, statusText) {
  const detail = body?.detail;
  return typeof detail === "string" ? detail : `${status} ${statusText || "request failed"}`;
}

async function parse(response) {
  const text = await response.text();
  let body = null;
  try { body = text ? JSON.parse(text) : null; } catch { body = text; }
  if (!response.ok) throw new ApiError(response.status, detailOf(body, response.status, response.statusText));
  return body;
}

/** JSON request; `body` is sent as JSON unless it is FormData. `options`: more fetch() options. */
export async function api(method, url, body, options = {}) {
  const init = { ...options, method, headers: {} };
  if (body instanceof FormData) init.body = body;
  else if (body !== undefined) {
    init.body = JSON.stringify(body);
    init.headers["Content-Type"] = "application/json";
  }
  let response;
  try {
    response = await fetch(url, init);
  } catch (err) {
    console.warn(`${method} ${url}:`, err);   // the request, for whoever debugs; the person gets what to do
    throw new ApiError(0, `${UNREACHABLE} (${err.message})`);
  }
  return parse(response);
}

export const get = (url) => api("GET", url);

/** A GET of `url` to call as often as needed, resolving to {body, newest}: `newest` is false for an
 *  answer that came after a later call was made (answers can cross, the later one landing first),
 *  which is then not to be shown over the later one's. */
export function latestGet(url) {
  let calls = 0;
  return async () => {
    const call = ++calls;
    const body = await get(url);
    return { body, newest: call === calls };
  };
}

/** POST multipart `form` with upload progress (fetch cannot report it); resolves to the JSON body. */
export function upload(url, form, onProgress) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", url);
    xhr.upload.onprogress = (e) => e.lengthComputable && onProgress(e.loaded / e.total);
    xhr.upload.onload = () => onProgress(1);
    xhr.onerror = () => reject(new ApiError(0, `upload failed: ${UNREACHABLE}`));
    xhr.onload = () => {
      const response = new Response(xhr.responseText, { status: xhr.status, statusText: xhr.statusText });
      parse(response).then(resolve, reject);
    };
    xhr.send(form);
  });
}

/** The error text a failed image URL would have returned (an <img> cannot read it). */
export async function failureOf(url) {
  try {
    await parse(await fetch(url));
    return "image could not be decoded";
  } catch (err) {
    return err.message;
  }
}
