// The REST calls the page makes (all relative to the page's server).
export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

let token = "";

/** Bearer token for mutating endpoints (only needed when the server was started with one). */
export function setToken(value) {
  token = value || "";
}

async function request(method, path, body, { timeoutMs = 15000 } = {}) {
  const controller = new AbortController();
  const timer = setTimeout(() => controller.abort(), timeoutMs);
  const headers = {};
  if (token && method !== "GET") headers.Authorization = `Bearer ${token}`;
  if (body !== undefined && !(body instanceof FormData)) headers["Content-Type"] = "application/json";
  try {
    const response = await fetch(`/v1${path}`, {
      method, headers, signal: controller.signal,
      body: body === undefined ? undefined : body instanceof FormData ? body : JSON.stringify(body),
    });
    const text = await response.text();
    let data = null;
    try {
      data = text ? JSON.parse(text) : null;
    } catch {
      data = { detail: text };
    }
    if (!response.ok) {
      throw new ApiError(response.status, describeError(data) || `${method} /v1${path}: HTTP ${response.status}`);
    }
    return data;
  } finally {
    clearTimeout(timer);
  }
}

function describeError(data) {
  if (!data) return null;
  const detail = data.detail ?? data.error ?? data.message;
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail)) return detail.map((d) => `${(d.loc || []).join(".")}: ${d.msg}`).join("; ");
  if (detail && typeof detail === "object") return detail.message || JSON.stringify(detail);
  return null;
}

export const api = {
  spaces: () => request("GET", "/spaces", undefined, { timeoutMs: 8000 }),
  graphs: () => request("GET", "/graphs", undefined, { timeoutMs: 8000 }),
  health: () => request("GET", "/health", undefined, { timeoutMs: 3000 }),
  request,
};
