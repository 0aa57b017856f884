// The side panels: the fleet table and the vehicle panel (parameters, presence, control,
// recent commands and events), and what they and the control panel (control.js) share
// to say an event or a lease. Each redraws from the Fleet state when it changes.

import { alarmBadges, alarmList } from "./alarms.js";
import {
  describeEvent, describeFailsafe, eventTitle, kindName, newerCommand, supersededBy,
} from "./describe.js";
import { commandName, isFinal, lastKnown, stageLabel } from "./fleet.js";
import { controlOffer } from "./grants.js";
import { patchChildren } from "./patch.js";
import { ago, clock, h, sending, sends, until } from "./ui.js";
import { lonStep } from "./wrap.js";

// said here before describe.js was split out; control.js reads them from here
export { describeData, describeEvent, describeFailsafe, kindName } from "./describe.js";

export function presenceBadge(presence) {
  return h(`span.presence.p-${presence || "offline"}`, {}, presence || "unknown");
}

/** A command's stage as a chip ({stage, label, last}): greyed, "(last known)", when the
 * vehicle is not online. */
function chip(cmd) {
  if (!cmd) return "–";
  return h(`span.chip.stage-${cmd.stage}${cmd.last ? ".last-known" : ""}`, {}, cmd.label);
}

/** A battery reading in whole percent, rounded down: 99.9 % against an alarm at 100 %
 * reads 99, never the 100 that would sit beside "low battery"; the same in the fleet
 * table and the vehicle panel. */
function batteryText(pct) {
  return pct == null ? "–" : `${Math.floor(pct)} %`;
}

/** A delay in ms as the console shows it (tenths below 10 ms). */
function millis(x) {
  return `${x < 10 ? x.toFixed(1) : x.toFixed(0)} ms`;
}

/** The course over ground from the trail: the bearing from where the vehicle was about
 * 5 s before its last position to that position; "–" when it moved under a metre. */
export function courseText(trail) {
  if (!trail || trail.length < 2) return "–";
  const last = trail[trail.length - 1];
  let from = trail[trail.length - 2];
  for (let i = trail.length - 2; i >= 0 && last.t - trail[i].t <= 5000; i -= 1) from = trail[i];
  const rad = Math.PI / 180;
  const north = (last.lat - from.lat) * 111320;
  const east = lonStep(from.lon, last.lon) * 111320 * Math.cos(last.lat * rad);
  if (Math.hypot(north, east) < 1) return "–";
  return `${Math.round((Math.atan2(east, north) / rad + 360) % 360) % 360} °`;
}

/** A command's detail as people read it: "superseded_by go_to c-1" is "superseded by the
 * go_to ana sent at 10:02:15" (``known``: a command as the console knows it), the id only
 * in its title; "superseded_by_stop" is "superseded by a stop". */
function readableDetail(detail, known) {
  if (detail === "superseded_by_stop") return "superseded by a stop";
  const by = supersededBy(detail);
  if (/^by \S+$/.test(detail || "")) return `cancelled ${detail}`; // "by mia": who cancelled it
  if (!by) return String(detail).replace(/_/g, " ");
  return h("span.superseded-by", { title: `command ${by.id}` },
    `superseded by ${newerCommand(by, known(by.id))}`);
}

/** The vehicle's link as the server measures it (docs/live.md, "Latency per hop"): the
 * round trip when it is known (timed on one clock, the vehicle's), and the one-way delay
 * (which leans on the vehicle's estimate of the server's clock) only where it cannot
 * read as more than the round trip: "19 ms one way · 13 ms round trip" said the clocks
 * disagreed, not the link. */
function linkText(view) {
  const { link_delay_ms: oneWay, link_rtt_ms: rtt } = view;
  if (rtt == null) return oneWay == null ? null : `${millis(oneWay)} one way`;
  return `${millis(rtt)} round trip${oneWay != null && oneWay <= rtt ? ` · ${millis(oneWay)} one way` : ""}`;
}

/** The table's figure for the link: the round trip when known, else the one-way delay. */
function linkFigure(view) {
  if (view.link_rtt_ms != null) return { ms: view.link_rtt_ms, what: "round trip to the server" };
  if (view.link_delay_ms != null) return { ms: view.link_delay_ms, what: "one-way delay to the server" };
  return null;
}

export function holderText(control, me) {
  if (!control) return "nobody";
  return control.holder === me.username ? "you" : control.holder;
}

/** Who holds control, in the vehicle panel's words (the phone's map says it so too,
 * holder.js): "ana holds control until 14:05:10", "you hold ...", "nobody holds control". */
export function controlSaid(control, me) {
  if (!control) return ["nobody holds control"];
  const mine = control.holder === me.username;
  return [h("b", {}, holderText(control, me)),
    ` ${mine ? "hold" : "holds"} control until ${clock(control.expires_at)}`];
}

/** A lease that lapses when its holder's consoles are all silent, said beside it (any
 * console the holder has open keeps it: the server hears the person, not one screen);
 * while this console's own link is lost (CSS), that the holder's may have lapsed already. */
function lapseSaid(timeoutS, mine) {
  const whose = mine ? "all your consoles are" : "all their consoles are";
  return h("small.lapse", {},
    h("span.lapse-live", {}, ` · lapses if ${whose} silent for ${timeoutS} s`),
    h("span.lapse-lost", {}, mine
      ? ` · this console is out of contact: it lapses ${timeoutS} s after the server last heard any console of yours, and may have`
      : ` · lapses if all their consoles are silent for ${timeoutS} s`));
}

/** Redraw at most once a frame, however many changes come in. */
export function throttled(fn) {
  let pending = false;
  return () => {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => {
      pending = false;
      fn();
    });
  };
}

// ---- the fleet table ------------------------------------------------------------------

export class FleetTable {
  constructor(ctx) {
    this.ctx = ctx;
    this.body = document.querySelector("#fleet-table tbody");
    this.drawn = new Map(); // vehicle id -> {key: its data as last drawn, row}
    this.render = throttled(() => this.draw());
    ctx.fleet.addEventListener("change", this.render);
  }

  draw() {
    const vehicles = [...this.ctx.fleet.vehicles.values()].sort((a, b) => (a.id < b.id ? -1 : 1));
    // A row whose data has not changed is not built again; the others are built and
    // patched into theirs (patch.js): each row and its tick box stay the same elements,
    // and the keyboard's focus where it is, while samples come in.
    const rows = vehicles.map((v) => {
      const d = this.rowData(v);
      const key = JSON.stringify(d);
      const had = this.drawn.get(v.id);
      return had && had.key === key && had.row.isConnected ? had.row : this.row(v.id, d, key);
    });
    patchChildren(this.body, rows);
    for (const row of this.body.children) this.drawn.get(row.dataset.vehicle).row = row;
  }

  /** Everything a row shows of a vehicle (its key: a row is built again when it changes). */
  rowData(v) {
    const { fleet, me } = this.ctx;
    const view = v.view;
    const p = view.position;
    const cmd = fleet.latestCommand(v.id);
    return {
      selected: this.ctx.selection.has(v.id), name: view.name || v.id, alarms: view.alarms || [],
      presence: view.presence, contact: fleet.lastContact(v.id), link: linkFigure(view),
      battery: p ? p.battery_pct : null, asOf: p ? p.ts : null, holder: holderText(v.control, me),
      cmd: cmd && { stage: cmd.stage, label: stageLabel(cmd, view.presence),
        last: lastKnown(cmd, view.presence) },
    };
  }

  row(id, d, key) {
    const alarmed = d.alarms.length > 0;
    const row = h(
      "tr",
      {
        dataset: { vehicle: id },
        class: [d.selected ? "selected" : "", alarmed ? "alarmed" : ""].join(" ").trim(),
        onclick: (e) => {
          if (e.target.type === "checkbox") return;
          this.ctx.pick(id, e.shiftKey || e.ctrlKey || e.metaKey);
          this.ctx.map.bringIntoView(id); // picked from the list: shown on the map
        },
      },
      h("td", {}, h("input", {
        type: "checkbox",
        checked: d.selected,
        "aria-label": `select ${id}`,
        onchange: () => this.ctx.pick(id, true),
      })),
      h("td", {}, h("b", {}, d.name), h("br"), h("small", {}, id),
        alarmed ? h("div.alarms", {}, ...alarmBadges({ alarms: d.alarms })) : null),
      h("td", {}, presenceBadge(d.presence), h("br"),
        h("small.ago", { dataset: { since: d.contact } }, ago(d.contact)),
        d.link
          ? [h("br"), h("small.link-delay", { title: d.link.what }, `link ${millis(d.link.ms)}`)]
          : null),
      // a reading of a vehicle not online is greyed and dated, as in its panel
      d.presence === "online"
        ? h("td.reading", {}, batteryText(d.battery))
        : h("td.stale", { title: d.asOf ? `as of ${clock(d.asOf)}` : null }, batteryText(d.battery)),
      h("td", {}, d.holder),
      h("td", {}, chip(d.cmd)),
    );
    this.drawn.set(id, { key, row });
    return row;
  }
}

// ---- one vehicle ------------------------------------------------------------------------

export class VehiclePanel {
  constructor(ctx) {
    this.ctx = ctx;
    this.el = document.getElementById("vehicle-pane");
    this.id = null;
    this.params = null;
    this.render = throttled(() => this.draw());
    ctx.fleet.addEventListener("change", (e) => {
      if (e.detail.id === this.id) this.render();
    });
  }

  show(id) {
    if (id !== this.id) {
      this.id = id;
      this.params = null;
      this.loadParams();
    }
    this.render();
  }

  async loadParams() {
    const v = this.ctx.fleet.vehicles.get(this.id);
    if (!v || !v.view.instance_id) return;
    const id = this.id;
    try {
      const got = await this.ctx.api.get("/client/get_param", { instance_id: v.view.instance_id });
      if (id !== this.id) return;
      this.params = { ...got, readAt: Date.now() }; // said: a refresh shows it read them
      this.render();
    } catch (e) {
      this.params = { error: e.message };
      this.render();
    }
  }

  draw() {
    const { fleet, me } = this.ctx;
    const v = fleet.vehicles.get(this.id);
    if (!v) {
      patchChildren(this.el, [h("p.hint", {}, "Select a vehicle on the map or in the fleet.")]);
      return;
    }
    const view = v.view;
    const p = view.position || {};
    const num = (x, unit, digits = 1) => (x == null ? "–" : `${Number(x).toFixed(digits)} ${unit}`);
    const known = (commandId) => fleet.command(v.id, commandId); // a superseding command
    const contact = fleet.lastContact(v.id);
    const control = v.control;
    const mine = control && control.holder === me.username;
    const controlRow = h(
      "div.control-line",
      {},
      controlSaid(control, me),
      control
        ? [" ", h("small.until", { dataset: { until: control.expires_at } }, `(${until(control.expires_at)})`),
          control.granted_by ? h("small", {}, ` granted by ${control.granted_by}`) : null,
          control.operator_timeout_s ? lapseSaid(control.operator_timeout_s, mine) : null]
        : null,
      control && !mine && this.ctx.controlPanel.managed(v.id)
        ? h("button", {
          ...sends(`revoke/${v.id}`), onclick: () => this.ctx.controlPanel.revoke(v),
        }, "Revoke")
        : null,
      mine ? null : controlOffer(this.ctx, v), // Take control (its manager) or Request
      mine ? h("button", {
        ...sends(`release/${v.id}`), onclick: () => this.ctx.commands.releaseControl(v.id),
      }, "Release") : null,
    );
    const failsafe = view.failsafe
      ? h("p.failsafe", {}, h("b", {}, "If the link is lost: "), describeFailsafe(view.failsafe),
        view.failsafe_acked === false ? " (not yet acknowledged by the vehicle)" : "")
      : null;
    // what is the same kept (patch.js): a focused button stays focused while samples come in
    patchChildren(this.el, [
      h("h2", {}, view.name || v.id, " ", presenceBadge(view.presence)),
      alarmList(view),
      h("p.sub", {}, `${v.id} · ${view.vehicle_type || "vehicle"} · mode ${view.control_mode || "–"}`),
      h("p", {}, "last contact ", h("b.ago", { dataset: { since: contact } }, ago(contact)),
        ` (${clock(contact)})`),
      failsafe,
      controlRow,
      view.presence && view.presence !== "online"
        ? h("p.stale-note", {}, `readings as of ${clock(p.ts)}: the vehicle is ${view.presence}`)
        : null,
      h(`dl.readings${view.presence && view.presence !== "online" ? ".stale" : ""}`, {},
        h("dt", {}, "position"), h("dd", {}, p.lat != null ? `${p.lat.toFixed(6)}, ${p.lon.toFixed(6)}` : "–"),
        h("dt", { title: "where the bow points" }, "heading"), h("dd", {}, p.heading_deg == null ? "–"
          : `${Math.round(p.heading_deg) % 360} °`), // 359.6 reads 0, not 360
        h("dt", { title: "where it moves, from its last positions" }, "course"),
        h("dd", {}, courseText(v.trail)),
        h("dt", {}, "speed"), h("dd", {}, num(p.speed_mps, "m/s")),
        h("dt", {}, "battery"), h("dd", {}, batteryText(p.battery_pct)),
        h("dt", {}, "link"), h("dd.link-delay", {}, linkText(view) || "–"),
        p.depth_m != null ? [h("dt", {}, "depth"), h("dd", {}, num(p.depth_m, "m"))] : null),
      h("h3", {}, "Parameters ", h("button.quiet", {
        ...sends(`params/${v.id}`), onclick: () => sending(`params/${v.id}`, () => this.loadParams()),
      }, "refresh")),
      this.paramsNote(view.presence),
      this.paramsTable(),
      h("h3", {}, "Recent commands"),
      this.commandList(v),
      h("h3", {}, "Recent events"),
      h("ol.events", {}, ...[...v.events].reverse().slice(0, 20).map((e) => h("li", {
        title: eventTitle(e),
      }, h("time", {}, clock(e.at)), " ", h("b", {}, kindName(e.kind)), " ", describeEvent(e, known)))),
    ]);
  }

  /** How old the parameters are: "as of 20:37:13" (when the vehicle last reported them;
   * "the vehicle is offline" when it is not online) and when this panel read them. */
  paramsNote(presence) {
    const got = this.params;
    if (!got || got.error || !got.readAt) return null;
    const away = presence && presence !== "online" ? `: the vehicle is ${presence}` : "";
    const asOf = got.updated_at ? `as of ${clock(got.updated_at)}${away}; ` : "";
    return h("p.params-note", {}, `${asOf}read at ${clock(got.readAt)}`);
  }

  paramsTable() {
    if (!this.params) return h("p.hint", {}, "loading…");
    if (this.params.error) return h("p.error", {}, this.params.error);
    const entries = Object.entries(this.params.params || {});
    if (!entries.length) return h("p.hint", {}, "none reported");
    return h("table.params", {}, ...entries.map(([k, val]) => h("tr", {}, h("th", {}, k),
      h("td", {}, typeof val === "object" ? JSON.stringify(val) : String(val)))));
  }

  commandList(v) {
    const cmds = this.ctx.fleet.recentCommands(v.id).slice(0, 12);
    if (!cmds.length) return h("p.hint", {}, "none");
    return h("ol.commands", {}, ...cmds.map((c) => h(
      lastKnown(c, v.view.presence) ? "li.last-known" : "li",
      { dataset: { command: c.command_id, stage: c.stage } },
      h("b", {}, commandName(c.type)), " ", h("span.steps", {}, c.stages.join(" → "),
        lastKnown(c, v.view.presence) ? " (last known)" : ""),
      c.progress != null && !isFinal(c.status) ? ` ${Math.round(c.progress * 100)} %` : "",
      h("br"),
      h("small", {}, `${clock(c.issued_at)}${c.issued_by ? ` by ${c.issued_by === "system" ? "the server" : c.issued_by}` : ""}`,
        c.detail && c.detail !== `by ${c.issued_by}` // cancelled by its sender: said once
          ? [" · ", readableDetail(c.detail, (id) => this.ctx.fleet.command(v.id, id))] : ""),
      !isFinal(c.status) && this.mayCancel(v, c)
        ? h("button.quiet", {
          ...sends(`cancel/${c.command_id}`),
          onclick: () => this.ctx.commands.cancelCommand(c.command_id),
        }, "cancel")
        : null,
    )));
  }

  /** Who the server lets cancel (docs/commands.md): the issuer, the control holder, a
   * manager of the vehicle or an admin. Offered to them only, not refused after a click. */
  mayCancel(v, c) {
    const me = this.ctx.me;
    if (me.role === "admin" || (me.role === "manager" && me.vehicles.includes(v.id))) return true;
    if (me.role === "viewer") return false;
    return c.issued_by === me.username || (v.control && v.control.holder === me.username);
  }
}
