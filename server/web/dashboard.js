// fleet-cloud dashboard: the fleet on a map and in a table, refreshed every second.
"use strict";

const state = { token: sessionStorage.getItem("fleet-token") || "", timer: null };

function api(path, options = {}) {
  const headers = { Authorization: `Bearer ${state.token}`, ...(options.headers || {}) };
  return fetch(path, { ...options, headers }).then(async (r) => {
    const body = await r.json().catch(() => ({}));
    if (!r.ok) throw new Error(body.error ? `${body.error.code}: ${body.error.message}` : r.status);
    return body;
  });
}

function text(tag, value, cls) {
  const el = document.createElement(tag);
  el.textContent = value;
  if (cls) el.className = cls;
  return el;
}

function drawMap(vehicles) {
  const svg = document.getElementById("map");
  svg.replaceChildren();
  const placed = vehicles.filter((v) => v.position);
  if (!placed.length) return;
  const lats = placed.map((v) => v.position.lat), lons = placed.map((v) => v.position.lon);
  const pad = 0.0005;
  const [minLat, maxLat] = [Math.min(...lats) - pad, Math.max(...lats) + pad];
  const [minLon, maxLon] = [Math.min(...lons) - pad, Math.max(...lons) + pad];
  for (const v of placed) {
    const x = ((v.position.lon - minLon) / (maxLon - minLon)) * 600;
    const y = (1 - (v.position.lat - minLat) / (maxLat - minLat)) * 400;
    const dot = document.createElementNS("http://www.w3.org/2000/svg", "circle");
    dot.setAttribute("cx", x); dot.setAttribute("cy", y); dot.setAttribute("r", 7);
    dot.setAttribute("class", v.presence);
    dot.setAttribute("fill", v.presence === "online" ? "#1e7d32" : "#8a8f94");
    const label = document.createElementNS("http://www.w3.org/2000/svg", "text");
    label.setAttribute("x", x + 10); label.setAttribute("y", y + 4);
    label.textContent = v.vehicle_id;
    svg.append(dot, label);
  }
}

function drawTable(vehicles) {
  const body = document.querySelector("#fleet tbody");
  body.replaceChildren();
  for (const v of vehicles) {
    const row = document.createElement("tr");
    const p = v.position;
    row.append(
      text("td", v.vehicle_id), text("td", v.name), text("td", v.presence, v.presence),
      text("td", p ? `${p.lat.toFixed(5)}, ${p.lon.toFixed(5)}` : "–"),
      text("td", p && p.battery_pct != null ? `${p.battery_pct.toFixed(0)} %` : "–"),
      text("td", v.control ? v.control.holder : "–"),
    );
    const cell = document.createElement("td");
    if (v.instance_id && v.presence !== "finished") {
      const stop = text("button", "Stop", "stop");
      stop.onclick = () => api("/client/submit_control", {
        method: "POST", headers: { "content-type": "application/json" },
        body: JSON.stringify({ instance_ids: [v.instance_id], command: { type: "stop", args: {} } }),
      }).catch((e) => setStatus(e.message));
      cell.append(stop);
    }
    row.append(cell);
    body.append(row);
  }
}

function setStatus(message) { document.getElementById("status").textContent = message; }

async function refresh() {
  try {
    const { vehicles } = await api("/api/vehicles");
    drawMap(vehicles); drawTable(vehicles);
    setStatus(`${vehicles.length} vehicles · ${new Date().toLocaleTimeString()}`);
  } catch (e) { setStatus(e.message); }
}

document.getElementById("login").addEventListener("submit", (ev) => {
  ev.preventDefault();
  state.token = document.getElementById("token").value.trim();
  sessionStorage.setItem("fleet-token", state.token);
  clearInterval(state.timer);
  refresh();
  state.timer = setInterval(refresh, 1000);
});
if (state.token) { refresh(); state.timer = setInterval(refresh, 1000); }
