// The page's REST and WebSocket addresses and credentials (wire protocol v1, docs/protocol.md).
// Credentials: static/common/auth.mjs, shared with the dashboard.

import { auth } from "../common/auth.mjs";

export { auth };

/** An HTTP answer that was not 2xx: `status`, the server's own words (`detail`) and, when
 * the server said when to try again (503 busy), `retryAfterS`. */
export class ApiError extends Error {
  constructor(status, detail, retryAfterS = null) {
    super(detail);
    this.status = status;
    this.detail = detail;
    this.retryAfterS = retryAfterS;
  }
}

function detailOf(body, fallback) {
  const detail = body && body.detail;
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail)) {
    // FastAPI's validation errors: "field: message", one per problem.
    return detail.map((d) => `${(d.loc || []).slice(1).join(".")}: ${d.msg}`).join("; ");
  }
  return fallback;
}

/**
 * A REST call on this page's own origin. `sid` picks the credential (the session's token,
 * else the API key); `body` is sent as JSON, or as it is when it is a Blob (typed by the
 * blob's own type: a recorded question's "audio/webm;codecs=opus"). Throws ApiError naming
 * what the server said, or a TypeError when the network is down.
 */
export async function request(method, path, { sid = null, body = undefined, params = null, signal } = {}) {
  const url = new URL(path, location.origin);
  for (const [key, value] of Object.entries(params || {})) url.searchParams.set(key, String(value));
  const headers = { Accept: "application/json" };
  const credential = auth.forSession(sid);
  if (credential) headers.Authorization = `Bearer ${credential}`;
  const binary = body instanceof Blob;
  if (body !== undefined) headers["Content-Type"] = binary ? body.type : "application/json";
  const response = await fetch(url, {
    method,
    headers,
    body: body === undefined || binary ? body : JSON.stringify(body),
    signal,
  });
  const text = await response.text();
  let parsed = null;
  try {
    parsed = text ? JSON.parse(text) : null;
  } catch {
    parsed = null;
  }
  if (!response.ok) {
    const retryAfterS = Number(response.headers.get("Retry-After")) || null;
    throw new ApiError(response.status, detailOf(parsed, `${response.status} ${response.statusText}`), retryAfterS);
  }
  return parsed;
}

/** A WebSocket URL on this page's origin (ws: or wss: as the page), the credential as ?token=. */
export function socketUrl(path, { sid = null, params = null } = {}) {
  const url = new URL(path, location.origin);
  url.protocol = location.protocol === "https:" ? "wss:" : "ws:";
  for (const [key, value] of Object.entries(params || {})) url.searchParams.set(key, String(value));
  const credential = auth.forSession(sid);
  if (credential) url.searchParams.set("token", credential);
  return url.toString();
}

/** The `#session=SID&token=TOKEN` fragment, if the page was opened with one. */
export function sessionFromFragment(hash = location.hash) {
  const params = new URLSearchParams(hash.replace(/^#/, ""));
  const sid = params.get("session");
  return sid ? { sid, token: params.get("token") || "" } : null;
}
