// HTTP calls to the server with the session's token (Authorization: Bearer), and the
// token itself, kept in sessionStorage (gone when the tab closes).

const TOKEN_KEY = "fleet-token";
const PASTED_KEY = "fleet-token-pasted";

export function savedToken() {
  return sessionStorage.getItem(TOKEN_KEY);
}

/** Keep the session's token, and whether it was pasted (an API token) rather than given
 * for a password; ``null`` drops the token but not that mark, so that the login page
 * that follows knows what to ask for. */
export function saveToken(token, { pasted = false } = {}) {
  if (token) {
    sessionStorage.setItem(TOKEN_KEY, token);
    if (pasted) sessionStorage.setItem(PASTED_KEY, "1");
    else sessionStorage.removeItem(PASTED_KEY);
  } else {
    sessionStorage.removeItem(TOKEN_KEY);
  }
}

/** Drop the token and its mark (logging out). */
export function forgetToken() {
  sessionStorage.removeItem(TOKEN_KEY);
  sessionStorage.removeItem(PASTED_KEY);
}

export function tokenWasPasted() {
  return sessionStorage.getItem(PASTED_KEY) === "1";
}

/** A refusal or failure, with the contract's error code, message and details. */
export class ApiError extends Error {
  constructor(status, code, message, details) {
    super(message);
    this.status = status;
    this.code = code;
    this.details = details;
  }

  /** The message, with the first detail's when it names an instance or a field and the
   * message does not already say it ("no such user: no such user"). */
  explain() {
    const first = Array.isArray(this.details) ? this.details[0] : null;
    if (first && first.message && !this.message.includes(first.message)) {
      return `${this.message}: ${first.message}`;
    }
    return this.message;
  }
}

/** POST /auth/token: a session token for a username and password. */
export async function login(username, password) {
  const r = await fetch("/auth/token", {
    method: "POST",
    headers: { "content-type": "application/json" },
    body: JSON.stringify({ username, password }),
  });
  const body = await r.json().catch(() => ({}));
  if (!r.ok) throw toError(r.status, body);
  return body.access_token;
}

function toError(status, body) {
  const e = (body && body.error) || {};
  return new ApiError(status, e.code || `http_${status}`, e.message || `HTTP ${status}`, e.details);
}

export class Api {
  /** onUnauthorized: called once the server says the token is no good (401). */
  constructor(token, onUnauthorized) {
    this.token = token;
    this.onUnauthorized = onUnauthorized;
  }

  async request(method, path, { body, query, raw = false } = {}) {
    const url = new URL(path, location.origin);
    for (const [k, v] of Object.entries(query || {})) {
      if (v !== undefined && v !== null && v !== "") url.searchParams.set(k, v);
    }
    const headers = { Authorization: `Bearer ${this.token}` };
    if (body !== undefined) headers["content-type"] = "application/json";
    let r;
    try {
      r = await fetch(url, {
        method,
        headers,
        body: body === undefined ? undefined : JSON.stringify(body),
      });
    } catch (e) {
      throw new ApiError(0, "unreachable", "the server cannot be reached", null);
    }
    if (r.status === 401) this.onUnauthorized();
    if (!r.ok) throw toError(r.status, await r.json().catch(() => ({})));
    return raw ? r.text() : r.json();
  }

  get(path, query) {
    return this.request("GET", path, { query });
  }

  post(path, body) {
    return this.request("POST", path, { body });
  }

  /** POST /client/submit_control: {commands (one per instance), warnings (sentences)}. */
  async submit(instanceIds, type, args, ttlS) {
    const body = { instance_ids: instanceIds, command: { type, args }, ttl_s: ttlS };
    const answer = await this.post("/client/submit_control", body);
    return { commands: answer.commands, warnings: answer.warnings || [] };
  }
}
