// Logging in, and the session: the login page (a password, or a token pasted), the
// console opened with the token this tab keeps, and the login page again, saying why,
// once the token is refused (a 401; the live link closed with 4401/4403) or the user
// logs out.

import { Api, forgetToken, login, saveToken, savedToken, tokenWasPasted } from "./api.js";
import { h, sending } from "./ui.js";

const $ = (id) => document.getElementById(id);

/** The login page, saying ``message``; ``token``: with the token field open and focused. */
function showLogin(message = "", { token = false } = {}) {
  $("app").hidden = true;
  $("login").hidden = false;
  $("login-error").textContent = message;
  if (token) $("login-token").closest("details").open = true;
  (token ? $("login-token") : $("login-user")).focus();
}

// What the login page says when a token is refused (401).
const REFUSED = {
  pasted: "this token was refused: it is wrong, revoked or expired",
  saved: "your session has ended (expired or revoked): sign in again",
  pastedEnded: "the token you pasted is no longer accepted (revoked, or a new one was made, " +
    "as a demo server does each time it starts): paste the new token the server printed",
};

/** The login page once a session has ended: one that began with a pasted token (the admin
 * token a demo prints, new at every start) asks for the new token, its field open. */
function showEnded() {
  if (tokenWasPasted()) showLogin(REFUSED.pastedEnded, { token: true });
  else showLogin(REFUSED.saved);
}

// Set before the page reloads on a refused token, read once by the page that follows.
const ENDED = "fleet-session-ended";

/** The token was refused: forget it and load the page again (``afterMs`` from now), which
 * then says the session has ended. */
export function endSession(afterMs = 0) {
  saveToken(null);
  sessionStorage.setItem(ENDED, "1");
  if (afterMs) setTimeout(() => location.reload(), afterMs);
  else location.reload();
}

/** Log out: the token forgotten, the login page again. */
export function logOut() {
  forgetToken();
  location.reload();
}

/** Open the console with ``token``: ``open(api, me, config, MapView)`` once the server has
 * said whose it is. ``fresh``: a token just pasted (its refusal says so). */
async function start(token, fresh, open) {
  let me;
  let started = false;
  const api = new Api(token, () => {
    if (!started) return; // the first call's refusal is said on the login page below
    endSession();
  });
  try {
    me = await api.get("/api/me");
    started = true;
  } catch (e) {
    saveToken(null);
    if (e.status !== 401) return showLogin(e.message);
    return fresh ? showLogin(REFUSED.pasted, { token: true }) : showEnded();
  }
  const config = await fetch("/console/config.json").then((r) => r.json()).catch(() => ({}));
  let MapView;
  try {
    ({ MapView } = await import("./map.js"));
  } catch (e) {
    document.body.replaceChildren(h("p.fatal", {},
      "The map library is missing on this server: run `npm ci` in server/web (make web)."));
    return undefined;
  }
  $("login").hidden = true;
  $("app").hidden = false;
  return open(api, me, config, MapView);
}

/** The login page wired to ``open`` the console (see ``start``); opened at once with the
 * token this tab keeps, else the login page, saying why when a session has just ended. */
export function startSession(open) {
  $("login-form").addEventListener("submit", (e) => {
    e.preventDefault();
    sending("login", async () => {
      try {
        const token = await login($("login-user").value.trim(), $("login-password").value);
        saveToken(token);
        $("login-password").value = "";
        await start(token, false, open);
      } catch (err) {
        $("login-error").textContent = err.message;
      }
    });
  });

  $("login-token-go").addEventListener("click", () => {
    const token = $("login-token").value.trim();
    if (!token) return;
    saveToken(token, { pasted: true });
    $("login-token").value = "";
    sending("login", () => start(token, true, open));
  });

  const token = savedToken();
  if (token) start(token, false, open);
  else if (sessionStorage.getItem(ENDED)) {
    sessionStorage.removeItem(ENDED);
    showEnded();
  } else showLogin();
}
