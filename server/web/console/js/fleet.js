// What the console knows of the fleet, kept from the live topics (docs/live.md gives each
// topic's data): the vehicles' views, their trails, commands, events and leases. Pure
// state: it tells its listeners what changed and draws nothing.

export const TRAIL_MINUTES = 5;
const RECENT_EVENTS = 50;
const RECENT_COMMANDS = 30;
const FINAL = new Set(["done", "failed", "rejected", "expired", "cancelled"]);

/** A command's stage as the console names it (the contract's status, "accepted" read as
 * "acked", a cancelled command that a stop superseded as "superseded"). */
export function stageOf(status, detail) {
  // cancelled by a stop ("superseded_by_stop") or replaced on the vehicle by a newer
  // command ("superseded_by go_to c-..."; an older server kept it as failed, "superseded by")
  if (status === "cancelled" && /^superseded_by/.test(detail || "")) return "superseded";
  if (status === "failed" && /^superseded by /.test(detail || "")) return "superseded";
  if (status === "accepted") return "acked";
  return status;
}

// How the console names each alarm (VehicleView.alarms; the message says it in full).
const ALARM_LABELS = {
  failsafe: "failsafe", no_go_zone: "no-go zone", outside_area: "outside area",
  low_battery: "low battery",
};

export function alarmLabel(kind) {
  return ALARM_LABELS[kind] || kind;
}

export function isFinal(status) {
  return FINAL.has(status);
}

// The stages that say what the vehicle itself does with a command (not the server's).
const ON_THE_VEHICLE = new Set(["delivered", "acked", "executing"]);

/** Whether a command's stage is only as last heard: the vehicle is not online (stale,
 * offline) and the command was under way on it, so what it does now is unknown. */
export function lastKnown(cmd, presence) {
  return Boolean(cmd) && presence !== "online" && ON_THE_VEHICLE.has(cmd.stage);
}

// How a person reads each command type: "go to", not go_to.
const COMMAND_NAMES = {
  go_to: "go to", keep_station: "keep station", follow_path: "follow path", stop: "stop",
};

/** A command type as people read it ("go to", "keep station"; another type with its
 * underscores as spaces). */
export function commandName(type) {
  return COMMAND_NAMES[type] || String(type || "").replace(/_/g, " ");
}

/** A command as the console labels it: "go to · executing", and "(last known)" after it
 * when that is all it knows. */
export function stageLabel(cmd, presence) {
  return `${commandName(cmd.type)} · ${cmd.stage}${lastKnown(cmd, presence) ? " (last known)" : ""}`;
}

/** The stages a command went through, from its history (each status once, in order). */
function stagesFromHistory(history) {
  const stages = [];
  for (const h of history || []) {
    if (h.status.startsWith("ack:")) continue; // an ack recorded and ignored
    const stage = stageOf(h.status, h.detail);
    if (stages[stages.length - 1] !== stage) stages.push(stage);
  }
  return stages;
}

function lastDetail(history) {
  const last = (history || [])[history.length - 1];
  return last ? last.detail : null;
}

function ms(ts) {
  return ts ? Date.parse(ts) : NaN;
}

/** A command as its events tell it (the earliest names who sent it, and when): null when
 * none of ``events`` is of it. */
export function commandFromEvents(events, commandId) {
  let first = null;
  for (const e of events) {
    const d = e.data || {};
    if (e.kind !== "command" || d.command_id !== commandId) continue;
    if (!first || Date.parse(e.at) < Date.parse(first.at)) first = e;
  }
  if (!first) return null;
  const d = first.data;
  const by = d.issued_by || (first.actor ? first.actor.replace(/^user:/, "") : null);
  return { type: d.type, issued_by: by, issued_at: first.at };
}

export class Fleet extends EventTarget {
  constructor() {
    super();
    /** vehicle_id -> vehicle record */
    this.vehicles = new Map();
  }

  vehicle(id) {
    let v = this.vehicles.get(id);
    if (!v) {
      v = {
        id,
        view: { vehicle_id: id, name: id, presence: "offline" },
        trail: [],
        commands: new Map(),
        events: [],
        control: null,
        index: this.vehicles.size,
      };
      this.vehicles.set(id, v);
    }
    return v;
  }

  changed(id, what) {
    this.dispatchEvent(new CustomEvent("change", { detail: { id, what } }));
  }

  /** The ``fleet`` topic: every vehicle (snapshot) or the one that changed. */
  applyFleet(data, snapshot) {
    for (const view of data.vehicles || []) {
      const known = this.vehicles.has(view.vehicle_id);
      const v = this.vehicle(view.vehicle_id);
      const was = v.view.presence;
      const alarmed = new Set((v.view.alarms || []).map((a) => a.kind));
      v.view = { ...v.view, ...view };
      const raised = (view.alarms || []).filter((a) => !alarmed.has(a.kind));
      // an update that says its alarms: those no longer in it have ended
      const now = new Set((view.alarms || []).map((a) => a.kind));
      const cleared = view.alarms ? [...alarmed].filter((kind) => !now.has(kind)) : [];
      if (known && (raised.length || cleared.length) && !snapshot) {
        this.dispatchEvent(new CustomEvent("alarms", { detail: { id: v.id, raised, cleared } }));
      }
      // a snapshot after a reconnect changes presence too: said as any change is
      if (known && view.presence && view.presence !== was) {
        this.dispatchEvent(new CustomEvent("presence", {
          detail: { id: v.id, was, now: view.presence },
        }));
      }
      if (view.control !== undefined) v.control = view.control;
      if (view.position) this.addToTrail(v, view.position);
      if (!known) this.dispatchEvent(new CustomEvent("added", { detail: { id: v.id } }));
      this.changed(v.id, "view");
    }
    if (snapshot) this.dispatchEvent(new CustomEvent("snapshot"));
  }

  applyTelemetry(id, sample) {
    // one dated too far ahead (a clock glitch: 2099) is never the position: taken as the
    // newest, it held the marker, since nothing later could replace it
    if (!sample || sample.ahead) return;
    const v = this.vehicle(id);
    const latest = v.view.position;
    if (!latest || !(ms(sample.ts) < ms(latest.ts))) v.view.position = sample;
    this.addToTrail(v, sample);
    this.changed(id, "position");
  }

  /** Older samples (the track of the last minutes, read once when the console starts). */
  seedTrail(id, points) {
    const v = this.vehicle(id);
    for (const p of points) this.addToTrail(v, p);
    this.changed(id, "trail");
  }

  addToTrail(v, sample) {
    const t = ms(sample.ts);
    if (!Number.isFinite(t) || sample.lat == null || sample.lon == null) return;
    const trail = v.trail;
    const point = { t, lat: sample.lat, lon: sample.lon };
    if (!trail.length || trail[trail.length - 1].t < t) trail.push(point);
    else if (!trail.some((p) => p.t === t)) {
      trail.push(point);
      trail.sort((a, b) => a.t - b.t);
    }
    const since = Date.now() - TRAIL_MINUTES * 60000;
    while (trail.length && trail[0].t < since) trail.shift();
  }

  applyControl(id, data) {
    const v = this.vehicle(id);
    v.control = data.control || null;
    v.view.control = v.control;
    this.changed(id, "control");
  }

  /** ``vehicle/<id>/commands``: whole command objects (snapshot) or one step of one. */
  applyCommands(id, data, snapshot) {
    const v = this.vehicle(id);
    // A snapshot (after a reconnect) replaces what was known: what it ended meanwhile is
    // said as if it had come live.
    const before = snapshot ? new Map([...v.commands].map(([k, c]) => [k, c.status])) : null;
    if (snapshot) v.commands.clear();
    for (const c of data.commands || []) {
      const had = v.commands.get(c.command_id);
      const was = snapshot ? before.get(c.command_id) : had && had.status;
      const cmd = had || { command_id: c.command_id, type: c.type, stages: [], args: null };
      if (c.history) {
        cmd.stages = stagesFromHistory(c.history);
        cmd.detail = lastDetail(c.history);
        cmd.issued_by = c.issued_by;
        cmd.issued_at = c.issued_at;
      }
      if (c.args) cmd.args = c.args;
      if (c.progress != null) cmd.progress = c.progress;
      if (c.issued_by) cmd.issued_by = c.issued_by;
      const ended = was !== undefined && !FINAL.has(was) && FINAL.has(c.status);
      cmd.status = c.status;
      if (c.detail !== undefined) cmd.detail = c.detail;
      cmd.stage = stageOf(cmd.status, cmd.detail);
      if (cmd.stages[cmd.stages.length - 1] !== cmd.stage) cmd.stages.push(cmd.stage);
      cmd.updatedAt = Date.now();
      if (!cmd.issued_at) cmd.issued_at = new Date().toISOString();
      v.commands.set(cmd.command_id, cmd);
      if (!had) this.dispatchEvent(new CustomEvent("command", { detail: { id, cmd } }));
      if (ended && c.status === "expired") {
        this.dispatchEvent(new CustomEvent("expired", { detail: { id, cmd } }));
      } else if (ended && cmd.stage !== "superseded" && ["failed", "rejected"].includes(c.status)) {
        this.dispatchEvent(new CustomEvent("failed", { detail: { id, cmd } }));
      }
    }
    for (const old of this.recentCommands(id).slice(RECENT_COMMANDS)) {
      v.commands.delete(old.command_id);
    }
    this.changed(id, "commands");
  }

  /** A command this console just submitted (its args are known here first). */
  noteSubmitted(id, commandId, type, args, user) {
    const v = this.vehicle(id);
    const cmd = v.commands.get(commandId);
    if (cmd) {
      cmd.args = cmd.args || args;
      cmd.issued_by = cmd.issued_by || user;
    } else {
      v.commands.set(commandId, {
        command_id: commandId, type, args, status: "queued", stage: "queued",
        stages: ["queued"], issued_by: user, issued_at: new Date().toISOString(),
      });
    }
    this.changed(id, "commands");
  }

  applyEvents(id, data, snapshot) {
    const v = this.vehicle(id);
    // A snapshot (after every reconnect) holds the server's last few events: merged with
    // those this console had, never in their place (what happened before would vanish).
    for (const e of data.events || []) {
      if (!v.events.some((x) => x.event_id === e.event_id)) v.events.push(e);
    }
    v.events.sort((a, b) => ms(a.at) - ms(b.at));
    v.events = v.events.slice(-RECENT_EVENTS);
    if (!snapshot) for (const e of data.events || []) this.applyToView(v, e);
    this.changed(id, "events");
    if (!snapshot) {
      for (const e of data.events || []) {
        this.dispatchEvent(new CustomEvent("event", { detail: { id, event: e } }));
      }
    }
  }

  /** What an event says of the vehicle's view that the ``fleet`` topic does not carry
   * (it changes on presence and link delay only): its control mode and failsafe policy. */
  applyToView(v, e) {
    const d = e.data || {};
    if (e.kind === "control_mode" && d.control_mode) v.view.control_mode = d.control_mode;
    else if (e.kind === "failsafe_changed" && d.action) {
      v.view.failsafe = d;
      v.view.failsafe_acked = false;
    } else if (e.kind === "failsafe_acked" && v.view.failsafe
      && (d.version == null || d.version === v.view.failsafe.version)) {
      v.view.failsafe_acked = true;
    }
  }

  /** Commands newest first. */
  recentCommands(id) {
    const v = this.vehicles.get(id);
    if (!v) return [];
    return [...v.commands.values()].sort((a, b) => ms(b.issued_at) - ms(a.issued_at));
  }

  /** A command of the vehicle as this console knows it, from its commands or else its
   * events ({type, issued_by, issued_at}); null when it knows neither. */
  command(id, commandId) {
    const v = this.vehicles.get(id);
    if (!v) return null;
    return v.commands.get(commandId) || commandFromEvents(v.events, commandId);
  }

  /** The command to show beside the vehicle: the newest one. */
  latestCommand(id) {
    return this.recentCommands(id)[0] || null;
  }

  /** When the vehicle was last heard of (its last contact or its latest sample). */
  lastContact(id) {
    const v = this.vehicles.get(id);
    if (!v) return NaN;
    const seen = ms(v.view.last_seen);
    const sample = v.view.position ? ms(v.view.position.ts) : NaN;
    if (Number.isNaN(seen)) return sample;
    if (Number.isNaN(sample)) return seen;
    return Math.max(seen, sample);
  }
}

export function topicsOf(id) {
  return ["telemetry", "commands", "events", "control"].map((k) => `vehicle/${id}/${k}`);
}
