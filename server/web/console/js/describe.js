// How the console says an event, a link-loss policy or an event's data in words: the
// vehicle panel's "Recent events", the control panel's "What happened" and the replay's
// timeline read each event through ``describeEvent``.

import { commandName, stageOf } from "./fleet.js";
import { clock } from "./ui.js";

/** " (on the vehicle since 10:02:11)": when the vehicle says a mode began, if it is not
 * when the server heard of it (a failsafe taken while the link was down). */
function sinceText(e) {
  const since = Date.parse((e.data || {}).since);
  if (!Number.isFinite(since) || Math.abs(Date.parse(e.at) - since) < 2000) return "";
  return ` (on the vehicle since ${clock(since)})`;
}

/** The newer command a superseded one names in its detail (the server's "superseded_by
 * keep_station c-9", an older server's "superseded by keep_station c-9"): ``{type, id}``;
 * null for any other detail (a stop's "superseded_by_stop" too). */
export function supersededBy(detail) {
  const m = /^superseded[_ ]by (\S+) (\S+)$/.exec(detail || "");
  return m ? { type: m[1], id: m[2] } : null;
}

/** The newer command as a person reads it, not its id: "the keep_station ana sent at
 * 10:02:15" (``known``: {issued_by, issued_at}, as the console knows it), or "a newer
 * keep_station" when the console does not know it. The id goes in a title. */
export function newerCommand(by, known) {
  const type = commandName(by.type);
  if (!known || !Number.isFinite(Date.parse(known.issued_at))) return `a newer ${type}`;
  const who = known.issued_by === "system" ? " the server" : known.issued_by ? ` ${known.issued_by}` : "";
  return `the ${type}${who} sent at ${clock(known.issued_at)}`;
}

/** The title of an event's line: the newer command's id, for one superseded ("the id
 * only as a secondary detail"); null for any other. */
export function eventTitle(e) {
  const by = e.kind === "command" ? supersededBy((e.data || {}).detail) : null;
  return by ? `superseded by command ${by.id}` : null;
}

/** An event in words. ``known(commandId)``: a command as the console knows it (who sent
 * it and when), to name a superseding command by more than its id. */
export function describeEvent(e, known = () => null) {
  const d = e.data || {};
  if (e.kind === "command") {
    const stage = d.status ? stageOf(d.status, d.detail) : "";
    const who = e.actor ? e.actor.replace(/^user:/, "") : null;
    const by = supersededBy(d.detail);
    // a cancel's detail is "by <who>": said once, not "(by ana) by ana"
    const detail = by ? ` (by ${newerCommand(by, known(by.id))})`
      : d.detail && d.detail !== "superseded_by_stop" && d.detail !== `by ${who}`
        ? ` (${String(d.detail).replace(/_/g, " ")})` : "";
    return `${commandName(d.type)} ${stage}${detail}` +
      (who ? ` by ${who === "system" ? "the server" : who}` : "");
  }
  if (e.kind === "control_mode") {
    return `${d.was ? `${d.was} → ` : ""}${d.control_mode || "?"}${sinceText(e)}`;
  }
  if (e.kind === "failsafe_changed") return describeFailsafe(d);
  if (e.kind === "zone_breach" || e.kind === "zone_cleared") {
    const what = d.message || `${e.kind === "zone_breach" ? "entered" : "left"} ${d.zone || "a zone"}`;
    const sent = d.command_type ? `; the server sent ${d.command_type.replace(/_/g, " ")}` : "";
    return `${what}${sent}`;
  }
  if (e.kind === "collision_risk") {
    const n = (x) => (x == null ? "?" : Math.round(x));
    return `with ${d.other_vehicle_id || "another vehicle"} in ${n(d.in_s)} s: ` +
      `closest ${n(d.closest_m)} m (${n(d.distance_now_m)} m apart now)`;
  }
  if (e.kind === "low_battery_cleared") {
    const pct = d.battery_pct == null ? "?" : Number(d.battery_pct).toFixed(0);
    const rule = d.threshold_pct == null ? "no battery alarm now"
      : `alarm below ${d.threshold_pct} % now`;
    return `${pct} % (${rule}: the failsafe changed)`;
  }
  if (e.kind === "low_battery" || e.kind === "battery_recovered") {
    const pct = d.battery_pct == null ? "?" : Number(d.battery_pct).toFixed(0);
    const why = d.reason === "failsafe_changed" ? ": the failsafe changed" : "";
    return `${pct} % (alarm below ${d.threshold_pct ?? "?"} %${why})`;
  }
  if (e.kind === "failsafe_entered") { // "failsafe entered (it was under remote control)"
    return `(it was ${modeWords(d.was)})${sinceText(e)}`;
  }
  if (e.kind === "failsafe_left") return `(now ${modeWords(d.control_mode)})${sinceText(e)}`;
  if (e.kind.startsWith("control_")) {
    const who = d.holder || d.user || d.username || "";
    const by = e.actor ? e.actor.replace(/^user:/, "") : "";
    const terms = e.kind === "control_grant" && d.expires_at
      ? ` until ${clock(d.expires_at)}` +
        (d.operator_timeout_s ? `, lapses after ${d.operator_timeout_s} s of silence` : "")
      : "";
    // "released by ben", not "released by ben (by ben)"; a request by whom asked
    if (e.kind === "control_request") return by ? `by ${by}` : "";
    if (e.kind === "control_expired") { // "control expired for ben: expired" said it twice
      if (d.reason === "operator_silent") {
        const heard = d.operator_seen_at ? `, none of their consoles heard since ${clock(d.operator_seen_at)}` : "";
        return `${who}: operator silent${heard}`;
      }
      return `${who}: its time ran out`;
    }
    return `${who}${terms}${d.reason ? `: ${String(d.reason).replace(/_/g, " ")}` : ""}` +
      `${by && by !== who ? ` (by ${by})` : ""}`;
  }
  if (e.kind === "hold_station") {
    // after "told to hold station": why, not "keeps station" said a second time (the
    // hold reaches a boat out of contact only when it is back)
    const why = String(d.reason || "ended").replace(/_/g, " ");
    const how = d.stop_kept ? "; the stop already sent to it holds it"
      : d.type === "stop" ? "; it is told to stop (it cannot keep station)" : "";
    return `${d.holder ? `${d.holder}'s control ended` : "control ended"} (${why})${how}`;
  }
  if (e.kind === "vehicle_changed") {  // an admin put its name or type right
    const was = d.was || {};
    const said = [];
    if (d.name != null) said.push(`name ${was.name ?? "(none)"} → ${d.name}`);
    if (d.vehicle_type != null) {
      said.push(`type ${was.vehicle_type ?? "(none)"} → ${d.vehicle_type}`);
    }
    return said.join(", ");
  }
  if (e.kind === "obstacles_changed") {  // an admin added or removed a fixed obstacle
    const who = e.actor ? e.actor.replace(/^user:/, "") : "";
    return `obstacle ${d.name || d.obstacle_id || ""} ${d.action || "changed"}${who ? ` by ${who}` : ""}`;
  }
  if (e.kind === "zones_changed") {  // an admin drew, changed or removed a zone
    const kind = d.kind === "no_go" ? "no-go zone" : d.kind === "operating_area"
      ? "operating area" : "zone";
    const who = e.actor ? e.actor.replace(/^user:/, "") : "";
    return `${kind} ${d.name || d.zone_id || ""} ${d.action || "changed"}` +
      `${who ? ` by ${who === "system" ? "the server" : who}` : ""}`;
  }
  if (e.kind === "presence") { // the server may find it late (it was down): when heard last
    const heard = d.last_seen ? Date.parse(d.last_seen) : NaN;
    const late = Number.isFinite(heard) && Date.parse(e.at) - heard > 60000;
    return `${d.presence || ""}${late ? ` (last heard ${clock(heard)})` : ""}`;
  }
  if (e.kind === "instance") return d.action || "";
  if (e.kind === "failsafe_acked") {
    if (d.version == null) return "";
    return d.version ? `(version ${d.version})` : "(the server's default)";
  }
  return describeData(d);
}

// An event's kind as a person reads it ("failsafe applied", not failsafe_acked); what
// describeEvent says follows it, so that a line reads as a sentence ("control granted to
// ana until 14:05:10 (by mia)"), the same in the vehicle panel, "What happened" and the
// replay.
/** A control mode in words ("remote" is "under remote control"). */
function modeWords(mode) {
  return { remote: "under remote control", local: "under local control", idle: "idle",
    failsafe: "in failsafe" }[mode] || mode || "?";
}

const KIND_NAMES = {
  failsafe_acked: "failsafe policy applied by the vehicle", failsafe_changed: "failsafe set",
  control_request: "control requested", control_grant: "control granted to",
  control_revoke: "control revoked from", control_release: "control released by",
  control_expired: "control expired for", control_deny: "request declined for",
  hold_station: "told to hold station:", instance: "instance",
  low_battery_cleared: "battery alarm lifted", vehicle_changed: "vehicle record changed:",
  zones_changed: "zones changed:",
  obstacles_changed: "obstacles changed:",
};

export function kindName(kind) {
  return KIND_NAMES[kind] || kind.replace(/_/g, " ");
}

/** A link-loss policy as a field manager reads it: "keep station where it is after 30 s
 * without the server; on a zone breach too · the server's default". */
export function describeFailsafe(f) {
  if (!f) return "";
  const what = {
    none: "carry on (no failsafe)",
    keep_station: "keep station where it is",
    stop: "stop",
    return_home: f.home ? `return home (${(+f.home.lat).toFixed(5)}, ${(+f.home.lon).toFixed(5)})`
      : "return home (where it started)",
  }[f.action] || String(f.action);
  const parts = [f.action === "none" ? what : `${what} after ${f.after_s ?? "?"} s without the server`];
  if (f.on_breach && f.action !== "none") parts.push("the same at once on a zone breach");
  if (f.low_battery_pct != null) parts.push(`low-battery alarm below ${f.low_battery_pct} %`);
  if (!f.version) parts.push("the server's default");
  return parts.join(" · ");
}

const UNITS = { s: " s", m: " m", pct: " %", mps: " m/s", deg: "°" };

/** An object as "key value · key value" (nulls left out, units from the key's suffix:
 * after_s 30 reads "after 30 s"; nested values as JSON). */
export function describeData(d) {
  return Object.entries(d || {})
    .filter(([, v]) => v !== null && v !== undefined)
    .map(([k, v]) => {
      const unit = k.match(/^(.*)_(s|m|pct|mps|deg)$/);
      const name = (unit ? unit[1] : k).replace(/_/g, " ");
      const value = typeof v === "object" ? JSON.stringify(v) : String(v);
      return `${name} ${value}${unit ? UNITS[unit[2]] : ""}`;
    })
    .join(" · ")
    .slice(0, 160);
}
