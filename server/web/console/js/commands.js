// What the console asks of the vehicles and the server for the person at it: a command
// sent to every selected vehicle at once (all or nothing, as the server does), a target
// far from its vehicle confirmed first, a stop (of the selection, or of every vehicle)
// confirmed first, a refusal said with what to do about it; control requested or
// released, a command cancelled.

import { shapeOnTheWay } from "./crossing.js";
import { commandName } from "./fleet.js";
import { holdAfter, holdText, takeControl } from "./grants.js";
import { clock, confirmAction, counted, dateTime, metresBetween, sending, toast } from "./ui.js";

const FAR_M = 5000; // a target farther than this from its vehicle is confirmed first
const TTL_S = 120; // how long a mission waits for its vehicle
const STOP_TTL_S = 3600; // a stop waits for a vehicle out of reach the longest a command may

/** The points a command sends its vehicles to (none for a stop or a hold where it is). */
export function targetPoints(type, args) {
  if (type === "follow_path") return args.path || args.waypoints || []; // as planned, if it was
  return args.lat != null ? [{ lat: args.lat, lon: args.lon }] : [];
}

/** The vehicle farthest from a point it is sent to, and how far: {name, m}, or null. */
function farthest(vehicles, points) {
  let out = null;
  for (const v of vehicles) {
    const here = v.view.position;
    if (!here) continue;
    for (const p of points) {
      const m = metresBetween(here, p);
      if (!out || m > out.m) out = { name: v.view.name || v.id, m };
    }
  }
  return out;
}

/** Why a command did not go: refused by the server, or never sent (no connection), in
 * which case each vehicle's own failsafe is what acts, after its link-loss time. */
function notSent(type, e) {
  const name = commandName(type);
  if (e.code === "unreachable") {
    return `${name} NOT sent: no connection to the server. Try again; a vehicle that ` +
      "hears nothing from it applies its failsafe after its link-loss time.";
  }
  return `${name} refused: ${e.explain()}`;
}

/** "A, B and C". */
function names(vehicles) {
  const all = vehicles.map((v) => v.view.name || v.id);
  return all.length > 1 ? `${all.slice(0, -1).join(", ")} and ${all[all.length - 1]}` : all.join("");
}

/** A warning of the server (written for any client: "plan: true") as the console says
 * it, in the words of its own controls and naming the boats. */
function saidHere(warning, vehicles) {
  const along = /^\d+ vehicles sent along one path, not planned: they will come within (\S+) m of each other/
    .exec(warning);
  if (along) {
    return `${names(vehicles)} follow the same path and will come within ${along[1]} m of each ` +
      "other; send each its own path to keep them apart";
  }
  return localTimes(warning.replace("(a path planned with plan: true goes round it)",
    "(a path sent with \u201cplan round obstacles\u201d ticked goes round it)"));
}

/** The contract's times in a server's sentence (2026-11-27T23:49:01.476Z) as the console
 * writes every time: this browser's clock (a day away, with its date). */
function localTimes(text) {
  return text.replace(/\b\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?Z\b/g, (iso) => {
    const t = Date.parse(iso);
    return Math.abs(Date.now() - t) < 86400000 ? clock(t) : dateTime(t);
  });
}

export class Commands {
  constructor(ctx) {
    this.ctx = ctx;
  }

  /** The vehicles of ``ids`` a command can go to: known, with an instance not finished. */
  targets(ids) {
    const out = [];
    for (const id of ids) {
      const v = this.ctx.fleet.vehicles.get(id);
      if (v && v.view.instance_id && v.view.presence !== "finished") out.push(v);
    }
    return out;
  }

  /** Submit one command to every selected vehicle (all or nothing, as the server does). */
  async send(type, args, ids = this.ctx.selection) {
    const { api, fleet, me } = this.ctx;
    const vehicles = this.targets(ids);
    if (!vehicles.length) {
      toast("no selected vehicle is running", "error");
      return false;
    }
    const far = farthest(vehicles, targetPoints(type, args));
    if (far && far.m > FAR_M) {
      const km = (far.m / 1000).toLocaleString(undefined, { maximumFractionDigits: 1 });
      const ok = await confirmAction({
        title: `Send ${far.name} ${km} km away?`,
        text: `The ${type === "follow_path" ? "path goes" : "target is"} ${km} km from where ` +
          `${far.name} is now: check the point (a click on a zoomed-out map lands far).`,
        confirm: type === "follow_path" ? "Send the path" : `Send ${commandName(type)} there`,
      });
      if (!ok) return false;
    }
    if (!(await this.clearOfObstacles(type, args, vehicles))) return false;
    try {
      const ids = vehicles.map((v) => v.view.instance_id);
      const ttl = type === "stop" ? STOP_TTL_S : TTL_S;
      const { commands: made, warnings } = await api.submit(ids, type, args, ttl);
      for (const c of made) {
        const v = vehicles.find((x) => x.view.instance_id === c.instance_id);
        if (v) fleet.noteSubmitted(v.id, c.command_id, type, args, me.username);
      }
      toast(`${commandName(type)} queued for ${vehicles.map((v) => v.view.name || v.id).join(", ")}`, "ok");
      for (const warning of warnings) toast(`note: ${saidHere(warning, vehicles)}`, "warn");
      if (args.speed_mps != null) this.topSpeeds(vehicles, args.speed_mps); // not awaited
      return true;
    } catch (e) {
      this.refused(type, e, vehicles);
      return false;
    }
  }

  /** A straight way (a go_to, a station away from the boat, a path not planned) that runs
   * into a known obstacle: asked first. True: send. */
  async clearOfObstacles(type, args, vehicles) {
    if (type === "follow_path" && args.plan) return true; // the server plans round them
    const points = targetPoints(type, args);
    if (!points.length) return true;
    const obstacles = this.ctx.liveObstacles || []; // not a replay's
    for (const v of vehicles) {
      const here = v.view.position;
      const hit = here && shapeOnTheWay([here, ...points], obstacles);
      if (!hit) continue;
      const name = v.view.name || v.id;
      const way = type === "follow_path" ? "path, as drawn," : "straight way there";
      return confirmAction({
        title: `${name}'s ${type === "follow_path" ? "path" : "way"} runs into ${hit.name}`,
        text: `${name}'s ${way} runs into ${hit.name}, a known fixed obstacle. ` +
          (type === "follow_path"
            ? "Tick \u201cplan round obstacles\u201d (one boat) to go round it, or draw the path clear of it."
            : "Send a path with \u201cplan round obstacles\u201d to go round it, or pick a point clear of it."),
        confirm: "Send it anyway",
      });
    }
    return true;
  }

  /** A speed asked above a vehicle's top speed (its ``max_speed_mps`` parameter, when it
   * reports one): said, as the server queues it as asked and the vehicle goes at its top. */
  async topSpeeds(vehicles, speed) {
    for (const v of vehicles) {
      try {
        const got = await this.ctx.api.get("/client/get_param",
          { instance_id: v.view.instance_id, names: "max_speed_mps" });
        const top = Number((got.params || {}).max_speed_mps);
        if (Number.isFinite(top) && top > 0 && speed > top) {
          toast(`note: ${v.view.name || v.id}'s top speed is ${top} m/s: it will go at that, ` +
            `not ${speed} m/s`, "warn");
        }
      } catch {
        // its parameters unread: nothing to say of its top speed
      }
    }
  }

  refused(type, e, vehicles) {
    const first = Array.isArray(e.details) ? e.details[0] : null;
    const code = (first && first.code) || e.code;
    if (code === "control_not_held") {
      const v = vehicles.find((x) => first && x.view.instance_id === first.instance_id) || vehicles[0];
      // its manager takes control (a grant to itself); an operator asks for it
      const ctx = this.ctx;
      const take = ctx.controlPanel.managed(v.id);
      // several boats: all or nothing, so none of them got it
      const none = vehicles.length > 1 ? `; NOT sent to any of the ${vehicles.length}` : "";
      toast(`${commandName(type)} refused: you do not hold control of ${v.view.name || v.id}${none}`, "error", take
        ? { label: "Take control", run: () => takeControl(ctx, v), sends: `grant/${v.view.instance_id}` }
        : { label: "Request control", run: () => this.requestControl(v.id), sends: `request/${v.id}` });
    } else if (vehicles.length > 1 && Array.isArray(e.details) && e.details.some((d) => d.instance_id)) {
      // each boat refused by name, in the server's words: all or nothing was sent
      const said = e.details.filter((d) => d.instance_id).map((d) => {
        const v = vehicles.find((x) => x.view.instance_id === d.instance_id);
        return `${v ? v.view.name || v.id : d.instance_id}: ${d.message}`;
      });
      toast(`${commandName(type)} NOT sent to any of them: ${said.join("; ")}`, "error");
    } else {
      toast(notSent(type, e), "error");
    }
  }

  async stopSelected() {
    const vehicles = this.targets(this.ctx.selection);
    if (!vehicles.length) return toast("no selected vehicle is running", "error");
    const names = vehicles.map((v) => v.view.name || v.id).join(", ");
    // a boat out of contact gets the stop only when it is back: not "at once"
    const here = vehicles.filter((v) => v.view.presence === "online");
    const away = vehicles.filter((v) => v.view.presence !== "online");
    const nameList = (list) => list.map((v) => v.view.name || v.id).join(", ");
    const said = [
      here.length ? `${nameList(here)} will stop at once` : null,
      away.length ? `${nameList(away)} ${away.length === 1 ? "is" : "are"} out of contact: ` +
        `the stop is queued and reaches ${away.length === 1 ? "it" : "each"} only when back, ` +
        "within an hour" : null,
    ].filter(Boolean).join("; ");
    const ok = await confirmAction({
      title: vehicles.length > 1 ? `Stop ${vehicles.length} vehicles?` : `Stop ${names}?`,
      text: `${said}; missions queued and not yet started are cancelled.`,
      confirm: vehicles.length > 1 ? `Stop ${vehicles.length} vehicles` : "Stop it",
    });
    if (!ok) return undefined;
    this.ctx.tools.set(null); // a map click after a stop must not send the vehicle off again
    await this.send("stop", {}, vehicles.map((v) => v.id));
    return undefined;
  }

  async stopAll() {
    const { api, fleet, me } = this.ctx;
    const running = this.targets(fleet.vehicles.keys());
    const away = running.filter((v) => v.view.presence !== "online").length;
    const ok = await confirmAction({
      title: "Stop every vehicle?",
      // "running" read as under way: these are the vehicles with an instance, idle or not
      text: `Every vehicle you can see (${running.length === 1 ? "1 vehicle" : `${running.length} vehicles`}` +
        (away ? `, ${away} of them not online: each gets it when back, within an hour` : "") +
        "); missions queued and not yet started are cancelled.",
      confirm: "Stop all vehicles",
    });
    if (!ok) return;
    this.ctx.tools.set(null);
    try {
      const { commands: made, warnings } = await api.submit(["*"], "stop", {}, STOP_TTL_S);
      for (const c of made) {
        const v = running.find((x) => x.view.instance_id === c.instance_id);
        if (v) fleet.noteSubmitted(v.id, c.command_id, "stop", {}, me.username);
      }
      toast(`stop sent to ${counted(made.length, "vehicle")}`, "ok");
      for (const warning of warnings) toast(`note: ${localTimes(warning)}`, "warn");
    } catch (e) {
      toast(notSent("stop", e), "error");
    }
  }

  requestControl(id) {
    return sending(`request/${id}`, async () => {
      const v = this.ctx.fleet.vehicles.get(id);
      try {
        const asked = await this.ctx.api.post("/client/request_control", { instance_id: v.view.instance_id });
        this.ctx.controlPanel.asked([asked]); // the button says so until an answer

        toast(`control of ${v.view.name || id} requested: the field manager decides`, "ok");
      } catch (e) {
        toast(`request refused: ${e.explain()}`, "error");
      }
    });
  }

  /** Give up control, after a confirmation (as Revoke): the vehicle holds station, and
   * commanding it again takes a new grant. */
  releaseControl(id) {
    return sending(`release/${id}`, () => this.release(id));
  }

  async release(id) {
    const v = this.ctx.fleet.vehicles.get(id);
    const name = v.view.name || id;
    const ok = await confirmAction({
      title: `Release your control of ${name}?`,
      text: `${holdText(name, v.view.presence)}; the commands you queued and it has not ` +
        "begun are cancelled. To command it again you ask for control.",
      confirm: "Release",
    });
    if (!ok) return;
    try {
      this.ctx.controlPanel.ending(id); // its hold_station event is said here, once
      await this.ctx.api.post("/client/release_control", { instance_id: v.view.instance_id });
      toast(`control of ${name} released; ${holdAfter(name, v.view.presence)}`,
        v.view.presence === "online" ? "ok" : "warn");
    } catch (e) {
      toast(`release refused: ${e.explain()}`, "error");
    }
  }

  cancelCommand(commandId) {
    return sending(`cancel/${commandId}`, async () => {
      try {
        await this.ctx.api.post("/client/cancel_command", { command_id: commandId });
      } catch (e) {
        toast(`cancel refused: ${e.explain()}`, "error");
      }
    });
  }
}
