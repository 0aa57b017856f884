// Who may be given control, and what a person is offered for a vehicle it does not hold:
// a field manager of the vehicle (or an admin) takes control (a grant to itself), an
// operator asks for it. The grant form picks the user from those who asked and those the
// console knows; a name it does not know is questioned before anything is sent.

import { holderText } from "./panels.js";
import { clock, confirmAction, h, sending, sends } from "./ui.js";

const TAKE_S = 3600; // a manager who takes control holds it for an hour

/** The button a person is offered for a vehicle it does not hold, or null (a viewer;
 * a vehicle with no instance). ``label``: the operator's ("Request control"). */
export function controlOffer(ctx, v, label = "Request control") {
  if (ctx.me.role === "viewer" || !v.view.instance_id) return null;
  if (ctx.controlPanel.managed(v.id)) {
    return h("button.primary.take", {
      ...sends(`grant/${v.view.instance_id}`),
      title: "grant control to yourself for 1 h (you manage this vehicle)",
      onclick: () => takeControl(ctx, v),
    }, "Take control");
  }
  const asked = ctx.controlPanel.requestedUntil(v);
  if (asked) {
    return h("button.requested", {
      disabled: true,
      title: `the field manager decides; your request stands until ${clock(asked)}`,
    }, "Requested…");
  }
  return h("button", {
    ...sends(`request/${v.id}`), onclick: () => ctx.commands.requestControl(v.id),
  }, label);
}

/** A manager of the vehicle grants its control to itself (asked first when another
 * holds it: that lease ends). */
export function takeControl(ctx, v) {
  return ctx.controlPanel.grant(v.view.instance_id, ctx.me.username, TAKE_S);
}

/** A grant to someone while another holds the vehicle ends that lease: asked first. */
export async function mayTakeOver(panel, instanceId, user) {
  const v = panel.vehicleOf(instanceId);
  const c = v && v.control;
  if (!c || c.holder === user || !(Date.parse(c.expires_at) > Date.now())) return true;
  const name = v.view.name || v.id;
  const holder = holderText(c, panel.ctx.me);
  if (user === panel.ctx.me.username) { // a manager taking control itself
    return confirmAction({
      title: `Take control of ${name} from ${c.holder}?`,
      text: `${c.holder} holds ${name} until ${clock(c.expires_at)}; take control ` +
        `yourself instead? ${c.holder}'s commands it has not begun are cancelled and ` +
        `${name} holds station.`,
      confirm: "Take control",
    });
  }
  return confirmAction({
    title: `Give control of ${name} to ${user}?`,
    text: `${holder} ${holder === "you" ? "hold" : "holds"} ${name} until ${clock(c.expires_at)}; ` +
      `give control to ${user} instead? ${holder === "you" ? "Your" : `${c.holder}'s`} commands ` +
      `it has not begun are cancelled and ${name} holds station.`,
    confirm: `Give it to ${user}`,
  });
}

/** The people the console knows who may be given control: {username: note}, those who
 * asked first. ``users``: every user (an admin's list), else null. */
export function knownUsers(panel, users) {
  const { fleet, me } = panel.ctx;
  const known = new Map();
  const add = (name, note) => {
    if (name && name !== me.username && !known.has(name)) known.set(name, note);
  };
  for (const r of panel.requests) {
    const v = panel.vehicleOf(r.instance_id);
    add(r.username, `asks for ${v ? v.view.name || v.id : r.instance_id}`);
  }
  for (const v of fleet.vehicles.values()) {
    if (v.control) add(v.control.holder, `holds ${v.view.name || v.id}`);
  }
  if (users) {
    for (const u of users) if (!u.disabled && u.role !== "viewer") add(u.username, u.role);
    return known;
  }
  for (const v of fleet.vehicles.values()) {
    for (const e of v.events) {
      if (!e.kind.startsWith("control_")) continue;
      const d = e.data || {};
      add(d.holder, "held control before");
      add(d.user, "asked before");
      if (e.kind === "control_request") add((e.actor || "").replace(/^user:/, ""), "asked before");
    }
  }
  return known;
}

/** The closest known name to a mistyped one (one or two letters off), or null. */
function nearest(name, names) {
  let best = null;
  for (const n of names) {
    const d = distance(name.toLowerCase(), n.toLowerCase());
    if (d <= 2 && (!best || d < best.d)) best = { n, d };
  }
  return best && best.n;
}

/** Edits from one name to the other, two letters swapped counting as one ("bne", "ben"). */
function distance(a, b) {
  const d = [...Array(a.length + 1)].map((_, i) => [i, ...Array(b.length).fill(0)]);
  for (let j = 1; j <= b.length; j++) d[0][j] = j;
  for (let i = 1; i <= a.length; i++) {
    for (let j = 1; j <= b.length; j++) {
      const cost = a[i - 1] === b[j - 1] ? 0 : 1;
      d[i][j] = Math.min(d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + cost);
      if (i > 1 && j > 1 && a[i - 1] === b[j - 2] && a[i - 2] === b[j - 1]) {
        d[i][j] = Math.min(d[i][j], d[i - 2][j - 2] + 1);
      }
    }
  }
  return d[a.length][b.length];
}

/** The grant form: a vehicle the manager manages, a user picked from those who asked
 * and those known (typed names are checked), how long, and when it lapses. */
export function grantForm(panel) {
  const vehicles = [...panel.ctx.fleet.vehicles.values()].filter(
    (v) => panel.managed(v.id) && v.view.instance_id && v.view.presence !== "finished",
  );
  const known = knownUsers(panel, panel.users);
  const check = panel.grantCheck; // what was said of the name last submitted
  return h("details.grant", {},
    h("summary", {}, "Grant control to someone"),
    h("form", {
      dataset: { key: "grant" },
      onsubmit: (e) => {
        e.preventDefault();
        const f = e.target;
        const v = panel.ctx.fleet.vehicles.get(f.vehicle.value);
        const user = f.user.value.trim();
        if (!v || !user) return;
        if (!known.has(user) && !(check && check.user === user && check.mayResend)) {
          questionUser(panel, user, [...known.keys()]);
          return;
        }
        panel.grantCheck = null;
        sending("grant/form", () => panel.grant(
          v.view.instance_id, user, +f.duration.value, +f.liveness.value,
        ).then((refusal) => {
          if (refusal) {
            panel.grantCheck = { user, message: refusal, mayResend: false };
            panel.render();
          }
        }));
      },
    },
    h("label", {}, "vehicle ", h("select", { name: "vehicle" },
      ...vehicles.map((v) => h("option", { value: v.id }, v.view.name || v.id)))),
    h("label", {}, "user ", h("input", {
      name: "user", required: true, autocomplete: "off", list: "grant-users",
      placeholder: known.size ? "pick or type a name" : "who asked for control",
      "aria-describedby": "grant-user-check",
      "aria-invalid": check ? "true" : null,
      oninput: () => {
        if (panel.grantCheck) {
          panel.grantCheck = null;
          panel.render();
        }
      },
    })),
    h("datalist", { id: "grant-users" },
      ...[...known].map(([name, note]) => h("option", { value: name, label: `${name}: ${note}` }))),
    check ? h("p.field-error", { id: "grant-user-check", role: "alert" }, check.message) : null,
    h("label", {}, "for ", panel.durationSelect("duration")),
    h("label", {}, "if their client falls silent: ", panel.livenessSelect("liveness")),
    h("button.primary", { type: "submit", ...sends("grant/form") },
      check && check.mayResend ? `Grant to ${check.user} anyway` : "Grant")));
}

/** A name the console does not know: said, with the likely one, and nothing sent. An
 * admin knows every user: an unknown name cannot be sent. A manager's list holds only
 * those it has seen, so the same name submitted again goes to the server, which checks. */
function questionUser(panel, user, names) {
  const guess = nearest(user, names);
  const admin = Boolean(panel.users);
  panel.grantCheck = {
    user,
    mayResend: !admin,
    message: `“${user}” is not ${admin ? "a user who may hold control" : "someone who asked for control or held it here"}` +
      (guess ? `: did you mean ${guess}?` : ".") +
      (admin ? " Nothing sent." : " Nothing sent: check the name, or grant again to let the server check it."),
  };
  panel.render();
}

/** What becomes of a boat whose control ends: it holds station at once when online; out
 * of contact, the hold waits for it, and expires if it is not back in time (only its own
 * link-loss failsafe acts then). */
export function holdText(name, presence) {
  return presence === "online" || presence === undefined
    ? `${name} holds station at once`
    : `${name} is ${presence}: the hold is queued and reaches it only when it is back in ` +
      "contact (if it is not back in time the hold expires, and only its own link-loss " +
      "failsafe acts)";
}

/** What becomes of a boat whose control ended, after a sentence that names it: "it holds
 * station" when online; out of contact, that the hold is only queued (holdText). */
export function holdAfter(name, presence) {
  return presence === "online" || presence === undefined ? "it holds station"
    : holdText(name, presence);
}
