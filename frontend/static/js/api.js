// The camcal HTTP API: one fetch wrapper, one error type, the operator token.
//
// Every API error has the shape {"error": {"code", "message", "detail"}};
// ApiError carries the message so the page can show it as it is (it says
// what to do). The operator token lives in sessionStorage: it is gone when
// the tab closes, and a page without it is read-only.

const TOKEN_KEY = "camcal.operator.token";
const NAME_KEY = "camcal.operator.name";

export class ApiError extends Error {
  constructor(status, code, message, detail) {
    super(message);
    this.status = status;
    this.code = code;
    this.detail = detail;
  }
}

export function operator() {
  const token = sessionStorage.getItem(TOKEN_KEY);
  return token ? { token, name: sessionStorage.getItem(NAME_KEY) || "operator" } : null;
}

function authHeaders() {
  const op = operator();
  return op ? { Authorization: `Bearer ${op.token}` } : {};
}

/** Query string from an object, leaving out empty values. */
export function query(params) {
  const q = new URLSearchParams();
  for (const [k, v] of Object.entries(params || {})) {
    if (v !== null && v !== undefined && v !== "") q.set(k, String(v));
  }
  const s = q.toString();
  return s ? `?${s}` : "";
}

async function errorFrom(res) {
  let body = null;
  try {
    body = await res.json();
  } catch {
    /* not JSON: a proxy or a crash page */
  }
  const e = body && body.error;
  if (e) return new ApiError(res.status, e.code, e.message, e.detail);
  return new ApiError(res.status, "http_error", `${res.status} ${res.statusText || "error"} from the server`);
}

/**
 * GET (or another method with `body`) a JSON resource of the API.
 * Throws ApiError with the server's message, or a network message.
 */
export async function api(path, { method = "GET", body, signal, token } = {}) {
  const headers = { Accept: "application/json", ...authHeaders() };
  if (token) headers.Authorization = `Bearer ${token}`;
  if (body !== undefined) headers["Content-Type"] = "application/json";
  let res;
  try {
    res = await fetch(path, {
      method,
      headers,
      body: body === undefined ? undefined : JSON.stringify(body),
      signal,
      cache: "no-store",
    });
  } catch (err) {
    if (err.name === "AbortError") throw err;
    throw new ApiError(0, "network", "the server cannot be reached; check the ship's network and retry");
  }
  if (!res.ok) {
    const err = await errorFrom(res);
    if (res.status === 401 || res.status === 403) {
      if (operator()) window.dispatchEvent(new CustomEvent("camcal:auth-failed", { detail: err }));
    }
    throw err;
  }
  if (res.status === 204) return null;
  return res.json();
}

/** Check a token against the server, then keep it for this tab. */
export async function login(token) {
  const who = await api("/api/operator", { token });
  sessionStorage.setItem(TOKEN_KEY, token);
  sessionStorage.setItem(NAME_KEY, who.operator);
  window.dispatchEvent(new CustomEvent("camcal:auth"));
  return who.operator;
}

export function logout() {
  sessionStorage.removeItem(TOKEN_KEY);
  sessionStorage.removeItem(NAME_KEY);
  window.dispatchEvent(new CustomEvent("camcal:auth"));
}
