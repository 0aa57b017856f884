// The map: Leaflet with an offline base (grid.js: a metric grid and a scale bar; a tile
// layer only when the server names one), the zones, obstacles and planned paths as
// vector layers, and each vehicle as a marker pointing along its heading, coloured by
// presence, with a label placed clear of its neighbours and a trail of the last minutes.

import * as L from "/vendor/leaflet/leaflet-src.esm.js";
import { alarmText } from "./alarms.js";
import { alarmLabel, isFinal, lastKnown, stageLabel } from "./fleet.js";
import { addBase } from "./grid.js";
import { placeLabels } from "./labels.js";
import { bindKeptTooltip, outlineBand } from "./tooltips.js";
import { at, drawn, setHome } from "./wrap.js";

export { L };

// A station circle at most this wide on screen can hide whole under a label: kept clear.
const SMALL_STATION_PX = 64;
const EARTH_M = 40075016.686; // the equator's length, in metres

const TRAIL_COLOURS = ["#1565c0", "#c2185b", "#00838f", "#6a1b9a", "#ef6c00", "#2e7d32",
  "#ad1457", "#4e342e"];

/** A GeoJSON position ([lon, lat]) drawn near the fleet's meridian (``L.geoJSON``'s option). */
export function coordsToLatLng(c) {
  return L.latLng(c[1], drawn(c[0]));
}

export function colourOf(index) {
  return TRAIL_COLOURS[index % TRAIL_COLOURS.length];
}

/** Text made safe to put in HTML (names come from vehicles and users: never markup). */
export function escapeHtml(text) {
  return String(text).replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);
}

function arrowHtml(view, label) {
  return `<svg class="arrow" viewBox="-13 -13 26 26" aria-hidden="true">
      <circle class="halo" r="12"></circle>
      <path d="M0,-10 L7,8 L0,4 L-7,8 Z"></path></svg>
    <div class="vlabel">${label}</div>`;
}

export class MapView {
  /**
   * fleet: the Fleet state. onPick(id, additive): a vehicle clicked (shift, ctrl or
   * cmd held: added to the selection). onMapClick(latlng): a click on the map itself.
   */
  constructor(el, config, fleet, { onPick, onMapClick }) {
    this.fleet = fleet;
    this.onPick = onPick;
    this.selected = new Set();
    this.markers = new Map();
    this.trails = new Map();
    this.missions = new Map();
    this.fitted = false;
    this.live = true;

    const map = L.map(el, { maxZoom: 22, minZoom: 2, zoomSnap: 0.5, worldCopyJump: true });
    this.map = map;
    map.setView([0, 0], 3);
    const bases = addBase(map, config); // the scale, the grid and its note, the server's tiles
    this.zones = L.featureGroup().addTo(map);
    this.obstacles = L.featureGroup().addTo(map);
    this.paths = L.featureGroup().addTo(map);
    this.trailLayer = L.featureGroup().addTo(map);
    this.vehicleLayer = L.featureGroup().addTo(map);
    this.draft = L.featureGroup().addTo(map);
    this.layers = L.control
      .layers(null, {
        ...bases,
        Zones: this.zones,
        Obstacles: this.obstacles,
        "Planned paths": this.paths,
        Trails: this.trailLayer,
      }, { collapsed: true })
      .addTo(map);
    new (L.Control.extend({ // back to every boat after zooming in (a phone has no wheel)
      options: { position: "topleft" },
      onAdd: () => {
        const button = L.DomUtil.create("button", "fit-all leaflet-bar");
        button.type = "button";
        button.textContent = "All boats";
        button.title = "show every boat on the map";
        L.DomEvent.disableClickPropagation(button);
        button.addEventListener("click", () => this.fitFleet());
        return button;
      },
    }))().addTo(map);

    map.on("click", (e) => onMapClick(e.latlng));
    map.on("zoomend moveend resize", () => this.scheduleLabels());
    fleet.addEventListener("change", (e) => this.update(e.detail.id, e.detail.what));
  }

  // ---- vehicles ---------------------------------------------------------------
  update(id, what) {
    const v = this.fleet.vehicles.get(id);
    if (!v) return;
    const p = v.view.position;
    if (p && p.lat != null) {
      if (setHome(p.lon)) this.redrawShapes(); // drawn near the fleet from now on
      this.placeMarker(v, p);
    }
    this.updateTrail(v);
    if (what === "commands" || what === "position" || what === "view") this.updateMission(v);
    this.scheduleLabels(); // after the mission too: a label keeps clear of a station's circle
  }

  placeMarker(v, p) {
    let m = this.markers.get(v.id);
    const latlng = at(p);
    if (!m) {
      const icon = L.divIcon({
        className: "vicon",
        html: arrowHtml(v.view, ""),
        iconSize: [26, 26],
        iconAnchor: [13, 13],
      });
      m = L.marker(latlng, { icon, title: v.id, keyboard: true, riseOnHover: true });
      m.on("click", (e) => {
        const ev = e.originalEvent || {};
        this.onPick(v.id, Boolean(ev.shiftKey || ev.ctrlKey || ev.metaKey));
      });
      // reached with Tab (role=button): Enter or Space selects it as a click does
      // (Leaflet turns neither into a click)
      m.on("keydown", (e) => {
        const ev = e.originalEvent;
        if (ev.key !== "Enter" && ev.key !== " ") return;
        ev.preventDefault();
        this.onPick(v.id, Boolean(ev.shiftKey || ev.ctrlKey || ev.metaKey));
      });
      m.addTo(this.vehicleLayer);
      this.markers.set(v.id, m);
    } else {
      m.setLatLng(latlng);
    }
    this.decorate(v, m);
  }

  decorate(v, m) {
    const el = m.getElement();
    if (!el) return;
    const view = v.view;
    el.dataset.vehicle = v.id;
    el.dataset.presence = view.presence || "offline";
    const alarms = view.alarms || [];
    el.classList.toggle("alarmed", alarms.length > 0);
    el.dataset.lat = view.position ? view.position.lat : "";
    el.dataset.lon = view.position ? view.position.lon : "";
    el.classList.toggle("selected", this.selected.has(v.id));
    const heading = view.position && view.position.heading_deg != null
      ? view.position.heading_deg : 0;
    el.querySelector("path").setAttribute("transform", `rotate(${heading})`);
    el.style.setProperty("--trail", colourOf(v.index));
    const cmd = this.fleet.latestCommand(v.id);
    const stale = lastKnown(cmd, view.presence) ? " last-known" : "";
    const chip = cmd
      ? `<span class="chip stage-${cmd.stage}${stale}">${escapeHtml(stageLabel(cmd, view.presence))}</span>`
      : "";
    const failsafe = view.control_mode === "failsafe" || view.control_mode === "local"
      ? `<span class="chip stage-failed">${escapeHtml(view.control_mode)}</span>` : "";
    // what is wrong, on the map too (a phone opens on it): the first alarm, and how many more
    const shown = failsafe ? alarms.filter((a) => a.kind !== "failsafe") : alarms;
    const alarm = shown.length
      ? `<span class="chip alarm-chip" title="${escapeHtml(shown.map(alarmText).join("; "))}">`
        + `${escapeHtml(alarmLabel(shown[0].kind))}${shown.length > 1 ? ` +${shown.length - 1}` : ""}</span>`
      : "";
    const html = `<b>${escapeHtml(view.name || v.id)}</b>${chip}${failsafe}${alarm}`;
    const label = el.querySelector(".vlabel");
    if (label.innerHTML !== html) {
      label.innerHTML = html;
      delete label.dataset.w; // measured again
    }
  }

  updateTrail(v) {
    let line = this.trails.get(v.id);
    const points = v.trail.map(at);
    if (!line) {
      line = L.polyline(points, {
        color: colourOf(v.index), weight: 3, opacity: 0.7, interactive: false,
        className: "trail",
      }).addTo(this.trailLayer);
      this.trails.set(v.id, line);
    } else {
      line.setLatLngs(points);
    }
  }

  /** The active command drawn on the map: a path, a go_to's target, a station's circle. */
  updateMission(v) {
    const old = this.missions.get(v.id);
    if (old) this.paths.removeLayer(old);
    const group = L.layerGroup();
    const colour = colourOf(v.index);
    const here = v.view.position;
    for (const cmd of this.fleet.recentCommands(v.id)) {
      if (isFinal(cmd.status) || !cmd.args) continue;
      const a = cmd.args;
      if (cmd.type === "follow_path") {
        const pts = (a.path || a.waypoints || []).map(at);
        if (here) pts.unshift(at(here));
        bindKeptTooltip(L.polyline(pts, {
          color: colour, weight: 2, dashArray: "6 6", className: `planned path-of-${v.id}`,
        }), `${escapeHtml(v.view.name || v.id)}: ${a.path ? "planned path" : "path"}`)
          .addTo(group);
        for (const w of a.waypoints || []) {
          L.circleMarker(at(w), { radius: 4, color: colour, fillOpacity: 1 })
            .addTo(group);
        }
      } else if (cmd.type === "go_to" && a.lat != null) {
        if (here) {
          L.polyline([at(here), at(a)], {
            color: colour, weight: 2, dashArray: "4 6", className: "planned",
          }).addTo(group);
        }
        bindKeptTooltip(
          L.circleMarker(at(a), { radius: 6, color: colour, fill: false, weight: 2 }),
          `${escapeHtml(v.view.name || v.id)}: go to`,
        ).addTo(group);
      } else if (cmd.type === "keep_station") {
        const centre = a.lat != null ? at(a) : here ? at(here) : null;
        if (centre) {
          L.circle(centre, {
            radius: a.radius_m || 2, color: colour, weight: 2, dashArray: "3 4", className: "station",
          }).addTo(group);
        }
      }
    }
    group.addTo(this.paths);
    this.missions.set(v.id, group);
  }

  /** The station circles small enough on screen for a label to hide them whole: boxes no
   * label should cover (a larger one shows past any label). */
  smallStations() {
    const boxes = [];
    for (const group of this.missions.values()) {
      group.eachLayer((layer) => {
        if (!(layer instanceof L.Circle)) return;
        const at = layer.getLatLng();
        const pt = this.map.latLngToContainerPoint(at);
        // metres per pixel at its latitude and the map's zoom (Web Mercator)
        const mpp = (EARTH_M * Math.cos((at.lat * Math.PI) / 180)) / 2 ** (this.map.getZoom() + 8);
        const r = layer.getRadius() / mpp + 3; // its dashed outline too
        if (2 * r <= SMALL_STATION_PX) boxes.push({ x: pt.x - r, y: pt.y - r, w: 2 * r, h: 2 * r });
      });
    }
    return boxes;
  }

  /** Pan to a vehicle that is off the map's view (its latest position), at the zoom it
   * has; one in view is left where it is. */
  bringIntoView(id) {
    const v = this.fleet.vehicles.get(id);
    const p = v && v.view.position;
    if (!p || p.lat == null || p.lon == null) return;
    const where = L.latLng(...at(p));
    if (!this.map.getBounds().pad(-0.1).contains(where)) this.map.panTo(where, { animate: false });
  }

  setSelected(ids) {
    this.selected = new Set(ids);
    for (const [id, m] of this.markers) {
      const el = m.getElement();
      if (el) el.classList.toggle("selected", this.selected.has(id));
    }
  }

  /** Show the live markers, or hide them while a replay is on. */
  showLive(on) {
    this.live = on;
    for (const layer of [this.vehicleLayer, this.trailLayer, this.paths]) {
      if (on) layer.addTo(this.map);
      else this.map.removeLayer(layer);
    }
    if (on) this.scheduleLabels();
  }

  fitFleet() {
    const pts = [...this.fleet.vehicles.values()]
      .map((v) => v.view.position)
      .filter((p) => p && p.lat != null)
      .map(at);
    if (!pts.length) return false;
    if (pts.length === 1) this.map.setView(pts[0], 17, { animate: false });
    else this.map.fitBounds(L.latLngBounds(pts).pad(0.6), { maxZoom: 18, animate: false });
    this.fitted = true;
    return true;
  }

  focus(id) {
    const v = this.fleet.vehicles.get(id);
    if (v && v.view.position) this.map.panTo(at(v.view.position));
  }

  // ---- labels -----------------------------------------------------------------
  scheduleLabels() {
    if (this.labelsPending) return;
    this.labelsPending = true;
    requestAnimationFrame(() => {
      this.labelsPending = false;
      this.placeAllLabels();
    });
  }

  placeAllLabels() {
    if (!this.live) return;
    const anchors = [];
    const labels = new Map();
    for (const [id, m] of this.markers) {
      const el = m.getElement();
      if (!el) continue;
      const label = el.querySelector(".vlabel");
      // measured once per text, but not while the map is hidden (a phone's other tab):
      // a size of 0 kept would let the label cover its neighbours once the map shows
      if (!+label.dataset.w && label.offsetWidth) {
        label.dataset.w = label.offsetWidth;
        label.dataset.h = label.offsetHeight;
      }
      const pt = this.map.latLngToContainerPoint(m.getLatLng());
      anchors.push({ id, x: pt.x, y: pt.y, w: +label.dataset.w, h: +label.dataset.h });
      labels.set(id, label);
    }
    const size = this.map.getSize();
    const placed = placeLabels(anchors, 13, { w: size.x, h: size.y }, this.smallStations());
    for (const [id, { dx, dy }] of placed) {
      const label = labels.get(id);
      label.style.left = `${13 + dx}px`;
      label.style.top = `${13 + dy}px`;
    }
  }

  // ---- the server's shapes ------------------------------------------------------
  /** The zones: no-go zones filled red, operating areas outlined blue. Neither's fill
   * answers the pointer (an operating area round the working water opened its name over the
   * boats wherever the pointer was): its name shows on or near its outline (tooltips.js),
   * and a click inside is the map's. */
  setZones(zones) {
    this.zoneList = zones;
    this.zones.clearLayers();
    for (const z of zones) {
      L.geoJSON(z.polygon, {
        coordsToLatLng,
        style: {
          className: `zone zone-${z.kind}`,
          color: z.kind === "no_go" ? "#c62828" : "#1565c0",
          weight: 2,
          dashArray: z.kind === "no_go" ? null : "8 6",
          fillOpacity: z.kind === "no_go" ? 0.18 : 0.03,
        },
        interactive: false,
      }).addTo(this.zones);
      const who = z.vehicles && z.vehicles.length ? ` (${z.vehicles.join(", ")})` : "";
      const kind = z.kind === "no_go" ? "no-go zone" : "operating area";
      const text = `${escapeHtml(z.name || z.zone_id)}: ${kind}${escapeHtml(who)}`;
      outlineBand(z.polygon, `zone-edge zone-edge-${z.kind}`, text).addTo(this.zones);
    }
  }

  setObstacles(obstacles) {
    this.obstacleList = obstacles;
    this.obstacles.clearLayers();
    for (const o of obstacles) {
      const shape = L.geoJSON(o.polygon, {
        coordsToLatLng,
        style: { className: "obstacle", color: "#5d4037", weight: 1, fillOpacity: 0.45 },
      });
      bindKeptTooltip(shape, `${escapeHtml(o.name)} (obstacle, clearance ${o.clearance_m} m)`)
        .addTo(this.obstacles);
    }
  }

  /** The zones and obstacles drawn again (near the fleet, once its meridian is known). */
  redrawShapes() {
    if (this.zoneList) this.setZones(this.zoneList);
    if (this.obstacleList) this.setObstacles(this.obstacleList);
  }

  // ---- drawing a path ----------------------------------------------------------------
  /** The path being drawn: its waypoints ({lat, lon}), numbered. */
  showDraft(waypoints) {
    this.draft.clearLayers();
    if (!waypoints.length) return;
    const points = waypoints.map(at);
    L.polyline(points, { color: "#ef6c00", weight: 3, dashArray: "2 6", className: "draft" })
      .addTo(this.draft);
    points.forEach((p, i) => {
      L.marker(p, {
        icon: L.divIcon({ className: "waypoint", html: `${i + 1}`, iconSize: [20, 20] }),
        interactive: false,
      }).addTo(this.draft);
    });
  }

  /** A short-lived mark where the user clicked (a go_to's or a station's point). */
  flash(latlng) {
    const mark = L.circleMarker(latlng, { radius: 10, color: "#ef6c00", weight: 3, fill: false })
      .addTo(this.draft);
    setTimeout(() => this.draft.removeLayer(mark), 1500);
  }
}
