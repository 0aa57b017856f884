// The console: log in (session.js), open the live link, and tie the map, the panels and
// the tools together. `window.fleetConsole` holds the pieces (for a look from the
// browser's developer tools, and for the browser tests).

import { Fleet, TRAIL_MINUTES, isFinal, topicsOf } from "./fleet.js";
import { LiveLink } from "./live.js";
import { ControlPanel } from "./control.js";
import { Commands } from "./commands.js";
import { FleetTable, VehiclePanel } from "./panels.js";
import { endSession, logOut, startSession } from "./session.js";
import { ago, clock, readNumber, sending, toast, until, zoneText } from "./ui.js";

const $ = (id) => document.getElementById(id);
const PHONE = window.matchMedia("(max-width: 760px)");
const TOUCH = window.matchMedia("(pointer: coarse)"); // a finger: no Esc, no ctrl-click
const SETTLE_MS = 1000; // after a tab switch, how long the rest of its multiple click is dropped

// ---- the console ----------------------------------------------------------------------

class Console {
  constructor(api, me, config, MapView) {
    this.api = api;
    this.me = me;
    this.app = $("app");
    $("stop-all").hidden = me.role === "viewer"; // a viewer reads; every stop needs an operator
    this.fleet = new Fleet();
    this.selection = new Set();
    this.focused = null;
    this.tool = null;
    this.draftPath = [];
    window.fleetConsole = this;

    $("who").textContent = `${me.username} · ${me.role}`;
    // Every time shown is this browser's local time: say in which zone, once.
    $("tz").textContent = `times in ${zoneText()}`;
    $("replay-zone").textContent = `local times, ${zoneText()}`;
    this.map = new MapView($("map"), config, this.fleet, {
      onPick: (id, additive) => this.pick(id, additive),
      onMapClick: (latlng) => this.mapClicked(latlng),
    });
    this.table = new FleetTable(this);
    this.vehiclePanel = new VehiclePanel(this);
    this.controlPanel = new ControlPanel(this);
    this.commands = new Commands(this); // sent from the bar, the panels and the toasts
    this.wireTabs();
    this.wireTools();

    this.fleet.addEventListener("added", (e) => {
      this.live.subscribe(topicsOf(e.detail.id));
      this.seedTrail(e.detail.id);
    });
    this.fleet.addEventListener("snapshot", () => {
      if (!this.map.fitted) this.map.fitFleet();
    });
    this.fleet.addEventListener("change", (e) => {
      if (e.detail.what === "view" && this.selection.has(e.detail.id)) this.selectionChanged();
    });
    this.fleet.addEventListener("event", (e) => {
      if (e.detail.event.kind === "zones_changed") this.loadShapes(); // a zone of a vehicle
    });
    this.fleet.addEventListener("presence", (e) => this.presenceChanged(e.detail));
    this.live = new LiveLink({
      token: api.token,
      pingTopic: `user/${me.username}/console-ping`,
      onEvent: (topic, data, snapshot) => this.onEvent(topic, data, snapshot),
      onState: (state, info) => this.linkState(state, info),
    });
    this.live.subscribe(["fleet", "zones"]);
    this.live.start();
    this.loadShapes();
    this.controlPanel.loadRequests();
    this.controlPanel.draw();
    setInterval(() => this.tick(), 1000);
    import("./replay.js").then(({ Replay }) => {
      this.replay = new Replay(this);
      this.replay.drawChoices();
      this.fleet.addEventListener("added", () => this.replay.drawChoices());
    });
  }

  onEvent(topic, data, snapshot) {
    if (topic === "fleet") return this.fleet.applyFleet(data, snapshot);
    if (topic === "zones") return this.loadShapes(); // drawn or removed: read them again
    const [, id, kind] = topic.split("/");
    if (kind === "telemetry") this.fleet.applyTelemetry(id, data);
    else if (kind === "commands") this.fleet.applyCommands(id, data, snapshot);
    else if (kind === "events") this.fleet.applyEvents(id, data, snapshot);
    else if (kind === "control") this.fleet.applyControl(id, data);
    return undefined;
  }

  linkState(state, info) {
    const link = $("link");
    link.dataset.state = state;
    this.app.dataset.link = state;
    if (state === "live") {
      link.textContent = "live";
      if (this.wasLost) {
        toast("link back: the view is up to date again", "ok");
        for (const id of this.fleet.vehicles.keys()) this.seedTrail(id);
        this.loadShapes();
      }
      this.wasLost = false;
    } else if (state === "lost") {
      this.wasLost = true;
      const s = Math.ceil(info.retryInMs / 1000);
      // on a phone short enough for the header's one row
      link.textContent = PHONE.matches ? `link lost · ${s} s` : `link lost · reconnecting in ${s} s`;
    } else if (state === "refused") {
      link.textContent = "refused: log in again";
      endSession(1500);
    } else {
      link.textContent = !this.wasLost ? "connecting…"
        : PHONE.matches ? "link lost · retrying" : "link lost · reconnecting…";
    }
  }

  /** A vehicle that goes offline in the middle of a command is said at once: its map label
   * would otherwise still read "executing". */
  presenceChanged({ id, now }) {
    if (now !== "offline") return;
    const cmd = this.fleet.latestCommand(id);
    if (!cmd || isFinal(cmd.status)) return;
    const v = this.fleet.vehicles.get(id);
    const heard = this.fleet.lastContact(id);
    toast(
      `${v.view.name || id} went offline during ${cmd.type.replace(/_/g, " ")} (${cmd.stage}); ` +
        `last heard ${Number.isFinite(heard) ? clock(heard) : "–"}: what it does now is unknown`,
      "error",
    );
  }

  /** Once a second: the "ago" and "until" texts move on (no call to the server). */
  tick() {
    const now = Date.now();
    this.keepLeasesAlive(now);
    for (const el of document.querySelectorAll("[data-since]")) {
      el.textContent = ago(+el.dataset.since, now);
    }
    for (const el of document.querySelectorAll("[data-until]")) {
      el.textContent = `(${until(el.dataset.until, now)})`;
    }
  }

  /**
   * While this user holds control of a vehicle whose lease needs a live client
   * (``operator_timeout_s``), say so: ``POST /client/heartbeat`` at a quarter of the
   * shortest such timeout (at most every second). Closing the console stops it, and the
   * lease lapses: the vehicle holds station.
   */
  keepLeasesAlive(now) {
    const held = [...this.fleet.vehicles.values()].filter((v) => {
      const c = v.control;
      return c && c.holder === this.me.username && c.operator_timeout_s && v.view.instance_id;
    });
    if (!held.length || this.heartbeatBusy) return;
    const every = Math.max(1000, (Math.min(...held.map((v) => v.control.operator_timeout_s)) * 1000) / 4);
    if (now - (this.lastHeartbeat || 0) < every) return;
    this.lastHeartbeat = now;
    this.heartbeatBusy = true;
    this.api.post("/client/heartbeat", { instance_ids: held.map((v) => v.view.instance_id) })
      .catch((e) => console.warn("heartbeat:", e.message))
      .finally(() => { this.heartbeatBusy = false; });
  }

  async seedTrail(id) {
    const from = new Date(Date.now() - TRAIL_MINUTES * 60000).toISOString();
    try {
      const track = await this.api.get(`/api/vehicles/${encodeURIComponent(id)}/track`, {
        from, max_points: 600,
      });
      this.fleet.seedTrail(id, track.points);
    } catch {
      // no trail yet: the live samples draw one
    }
  }

  /** Zones (when the server has them), obstacles. */
  async loadShapes() {
    try {
      this.map.setZones((await this.api.get("/api/zones")).zones || []);
    } catch (e) {
      if (e.status !== 404) console.warn("zones:", e.message);
    }
    try {
      this.map.setObstacles((await this.api.get("/api/obstacles")).obstacles || []);
    } catch (e) {
      console.warn("obstacles:", e.message);
    }
  }

  // ---- selection ----------------------------------------------------------------------
  pick(id, additive) {
    if (additive) {
      if (this.selection.has(id)) this.selection.delete(id);
      else this.selection.add(id);
    } else {
      this.selection = new Set([id]);
    }
    if (this.selection.has(id)) {
      this.focused = id;
      this.vehiclePanel.show(id);
      if (!additive && !PHONE.matches) this.showTab("vehicle");
    }
    this.selectionChanged();
  }

  selectionChanged() {
    this.map.setSelected(this.selection);
    this.table.render();
    const n = this.selection.size;
    // a viewer reads: no command tools (the server would refuse every one)
    const reads = this.me.role === "viewer";
    $("actions").hidden = n === 0 || this.app.dataset.replay === "on" || reads;
    const names = [...this.selection].map((id) => this.fleet.vehicles.get(id)?.view.name || id);
    $("selection").textContent = n ? `${n} selected: ${names.join(", ")}` : "";
    $("stop-selected").textContent = n > 1 ? `Stop ${n}` : "Stop";
    // The planner keeps boats apart, so one planned path cannot take several of them.
    const plan = $("path-plan");
    plan.disabled = n > 1;
    plan.parentElement.title = n > 1
      ? "one path for several boats is sent as drawn: the planner keeps boats apart, so it " +
        "plans a path for one boat at a time"
      : "";
    if (!n) this.setTool(null);
  }

  // ---- tabs ---------------------------------------------------------------------------
  wireTabs() {
    for (const b of document.querySelectorAll("[data-tab]")) {
      b.addEventListener("click", () => this.showTab(b.dataset.tab));
    }
    // A tab switch never acts on the click that caused it: a double click on a fleet row
    // opened the Vehicle tab with its first click, and its second landed on the Release
    // button that had just appeared under the pointer. The rest of a multiple click
    // (detail 2, 3, ...) that lands in the pane a click has just shown is dropped.
    window.addEventListener("click", (e) => {
      const s = this.switched;
      if (s && e.detail > 1 && e.timeStamp - s.at < SETTLE_MS && s.pane.contains(e.target)) {
        e.stopPropagation();
        e.preventDefault();
      }
      this.clicking = e; // a tab shown while this click is handled was shown by it
    }, true);
    window.addEventListener("click", () => { this.clicking = null; });
    this.showTab(PHONE.matches ? "map" : "fleet");
    PHONE.addEventListener("change", () => this.map.map.invalidateSize());
  }

  showTab(tab) {
    if (this.clicking && this.app.dataset.tab !== tab) {
      const pane = tab === "map" ? $("map-pane") : document.querySelector(`.side [data-pane="${tab}"]`);
      if (pane) this.switched = { at: this.clicking.timeStamp, pane };
    }
    this.app.dataset.tab = tab;
    for (const b of document.querySelectorAll("[data-tab]")) {
      b.setAttribute("aria-selected", String(b.dataset.tab === tab));
    }
    if (tab === "map") {
      requestAnimationFrame(() => {
        this.map.map.invalidateSize();
        this.map.scheduleLabels(); // labels changed while hidden are measured now
      });
    }
    if (tab === "control") this.controlPanel.loadRequests();
    if (tab === "replay" && this.replay) this.replay.drawChoices();
    if (tab === "vehicle") this.vehiclePanel.show(this.focused);
  }

  // ---- tools --------------------------------------------------------------------------
  wireTools() {
    for (const b of document.querySelectorAll("[data-tool]")) {
      b.addEventListener("click", () => this.setTool(this.tool === b.dataset.tool ? null : b.dataset.tool));
    }
    // each button that sends is disabled while its call is in flight (ui.js, sending)
    $("hold").addEventListener("click", () => sending("hold", async () => {
      const radius = this.radius();
      if (radius != null) await this.commands.send("keep_station", { radius_m: radius });
    }));
    $("stop-selected").addEventListener("click", () => sending("stop", () => this.commands.stopSelected()));
    $("stop-all").addEventListener("click", () => sending("stop-all", () => this.commands.stopAll()));
    $("path-undo").addEventListener("click", () => {
      this.draftPath.pop();
      this.drawDraft();
    });
    $("path-cancel").addEventListener("click", () => this.setTool(null));
    $("path-send").addEventListener("click", () => sending("path", () => this.sendPath()));
    $("logout").addEventListener("click", () => {
      this.live.stop();
      logOut();
    });
    document.addEventListener("keydown", (e) => {
      if (e.key === "Escape" && this.tool) this.setTool(null);
    });
  }

  setTool(tool) {
    this.tool = tool;
    for (const b of document.querySelectorAll("[data-tool]")) {
      b.classList.toggle("active", b.dataset.tool === tool);
      b.setAttribute("aria-pressed", String(b.dataset.tool === tool));
    }
    const hints = TOUCH.matches
      ? {
        go_to: "Tap the map where the selected vehicles should go (tap Go to again: cancel).",
        station: "Tap the map where the selected vehicles should keep station " +
          "(tap Keep station again: cancel).",
        path: "Tap the map to add waypoints, then Send path (or Cancel).",
      }
      : {
        go_to: "Click the map where the selected vehicles should go (Esc: cancel).",
        station: "Click the map where the selected vehicles should keep station (Esc: cancel).",
        path: "Click the map to add waypoints, then Send path (Esc: cancel).",
      };
    $("tool-hint").hidden = !tool;
    $("tool-hint").textContent = hints[tool] || "";
    $("path-bar").hidden = tool !== "path";
    this.app.dataset.tool = tool || "";
    if (tool === "path") this.map.map.doubleClickZoom.disable();
    else this.map.map.doubleClickZoom.enable();
    if (tool !== "path") {
      this.draftPath = [];
      this.drawDraft();
    }
  }

  drawDraft() {
    this.map.showDraft(this.draftPath.map((p) => [p.lat, p.lon]));
    $("path-count").textContent = `${this.draftPath.length} waypoint${this.draftPath.length === 1 ? "" : "s"}`;
  }

  mapClicked(latlng) {
    const point = { lat: +latlng.lat.toFixed(7), lon: +latlng.lng.toFixed(7) };
    if (this.tool === "go_to") {
      const speed = this.speedArg();
      if (speed == null) return; // said why; the tool stays for another click
      this.map.flash(latlng);
      this.commands.send("go_to", { ...point, ...speed });
      this.setTool(null);
    } else if (this.tool === "station") {
      const radius = this.radius();
      if (radius == null) return;
      this.map.flash(latlng);
      this.commands.send("keep_station", { ...point, radius_m: radius });
      this.setTool(null);
    } else if (this.tool === "path") {
      this.draftPath.push(point);
      this.drawDraft();
    }
  }

  /** The speed option: {} when left empty (the vehicle's own), ``{speed_mps}``, or null
   * (said in a toast) when it is not a plain number in the field's range: nothing is sent
   * then. */
  speedArg() {
    const field = $("opt-speed");
    const got = readNumber(field, { what: "speed", unit: "m/s", optional: "the vehicle's own" });
    if (got.error) return this.badNumber(field, got.error);
    return got.value === undefined ? {} : { speed_mps: got.value };
  }

  /** The station radius in metres, or null (said in a toast) when it is not a plain
   * number in its range. */
  radius() {
    const field = $("opt-radius");
    const got = readNumber(field, { what: "station radius", unit: "m" });
    return got.error ? this.badNumber(field, got.error) : got.value;
  }

  badNumber(field, error) {
    toast(error, "error");
    field.focus();
    return null;
  }

  async sendPath() {
    if (!this.draftPath.length) return toast("click the map to add waypoints first", "error");
    const speed = this.speedArg();
    if (speed == null) return undefined;
    const args = { waypoints: this.draftPath, ...speed };
    if ($("path-plan").checked && !$("path-plan").disabled) args.plan = true;
    if (await this.commands.send("follow_path", args)) this.setTool(null);
    return undefined;
  }
}

startSession((api, me, config, MapView) => new Console(api, me, config, MapView));
