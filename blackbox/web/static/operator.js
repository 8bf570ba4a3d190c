// The operator page: the vehicle live, its map, and the commands. A command is a request to the
// mission or movement manager (which decides); the page says "confirmed" only once the vehicle's
// own state shows it, never on the API's answer alone.
"use strict";

ARES.page(["operator"], "operator", async () => {
  const route = await ARES.json("/route");
  const vehicleId = route.vehicle_id;
  document.getElementById("vehicle").textContent = vehicleId;
  const app = document.getElementById("app");
  const lagEl = document.getElementById("lag");
  const status = document.getElementById("command-status");
  const eventsEl = document.getElementById("events");
  const processesEl = document.getElementById("processes");
  window.aresLag = [];                  // ms from the bus to this page, per frame (ares bench live reads it)
  let last = null;                      // the latest frame
  let pending = null;                   // {name, done(frame), since}

  // ---- the map: route, POIs, vehicle, predicted trajectory, obstacle area, occupied cells ----
  const map = ARES.map(document.getElementById("map"));
  let layers = null;
  let gridDrawn = 0;
  if (map) {
    ARES.drawRoute(map, route, true);
    layers = {
      cells: L.polygon([], {weight: 0, color: "#1d232a", fillOpacity: 0.6}).addTo(map),   // one shape: cheap to redraw
      area: L.polygon([], {color: "#b54708", weight: 1, fillOpacity: 0.15}).addTo(map),
      trajectory: L.polyline([], {color: "#2e90fa", weight: 3}).addTo(map),
      vehicle: L.circleMarker([0, 0], {radius: 8, color: "#b42318", fillOpacity: 0.9}).addTo(map),
      heading: L.polyline([], {color: "#b42318", weight: 3}).addTo(map),
    };
  }

  function draw(f) {
    if (!layers || !f.pose) return;
    const p = f.pose;
    layers.vehicle.setLatLng(ARES.ll(p.x, p.y));
    layers.heading.setLatLngs([ARES.ll(p.x, p.y), ARES.ll(p.x + 4 * Math.cos(p.yaw), p.y + 4 * Math.sin(p.yaw))]);
    layers.trajectory.setLatLngs(f.trajectory ? f.trajectory.x.map((x, i) => ARES.ll(x, f.trajectory.y[i])) : []);
    const area = f.obstacle && f.obstacle.area;
    layers.area.setLatLngs(area ? area.x.map((x, i) => ARES.ll(x, area.y[i])) : []);
    if (Date.now() - gridDrawn < 500) return;           // the occupied cells twice a second: enough to see, cheap
    gridDrawn = Date.now();
    const h = f.grid ? f.grid.cell_m : 0;
    layers.cells.setLatLngs(f.grid ? f.grid.x.map((x, i) => {
      const y = f.grid.y[i];
      return [ARES.ll(x, y), ARES.ll(x + h, y), ARES.ll(x + h, y + h), ARES.ll(x, y + h)];
    }) : []);
  }

  function processes(list) {
    processesEl.replaceChildren();
    for (const p of list || []) {
      const row = document.createElement("tr");
      row.append(ARES.text("td", p.name), ARES.text("td", p.state, p.state === "running" ? "" : "level-1"),
                 ARES.text("td", p.restarts ? p.restarts + " restarts" : ""));
      processesEl.append(row);
    }
  }

  function addEvents(list) {
    for (const e of list) {
      const li = ARES.text("li", ARES.clock(e.wall_ms) + "  " + e.source + ": " + e.message, e.level);
      li.dataset.kind = e.kind;
      eventsEl.prepend(li);
      if (e.kind === "snapshot" && e.request_id) {
        savedSnapshots.add(e.request_id);
        if (last) confirm(last);
      }
    }
    while (eventsEl.children.length > 100) eventsEl.lastChild.remove();
  }

  ARES.stream("/live/vehicles/" + encodeURIComponent(vehicleId), {
    frame(f) {
      last = f;
      const stamp = f.car_state_stamp_ms || f.car_state_wall_ms;   // published on the bus (real time), else reached the gateway
      if (stamp) {
        const lag = Date.now() - stamp;
        window.aresLag.push(lag);
        if (window.aresLag.length > 5000) window.aresLag.shift();
        lagEl.textContent = "live · " + Math.max(lag, 0).toFixed(0) + " ms behind the bus";
      } else {
        lagEl.textContent = "live · no vehicle data";
      }
      ARES.fill(app, f);
      const level = document.getElementById("level");
      level.className = f.awareness ? "level-" + f.awareness.level : "";
      processes(f.processes);
      draw(f);
      confirm(f);
    },
    events: addEvents,
    drop() { lagEl.textContent = "reconnecting…"; },
    error(why) { lagEl.textContent = "live refused: " + why; },
  });

  // ---- commands: sent, then confirmed by what the vehicle reports -------------------------
  const base = "/vehicles/" + encodeURIComponent(vehicleId);
  const COMMANDS = {
    start: {path: "/mission", body: {}, done: (f, before) => f.mission && f.mission.goal_id > before.goal &&
            f.mission.state !== "IDLE"},
    pause: {path: "/mission/pause", done: (f) => f.mission && f.mission.state === "PAUSED" && f.speed_mps <= 0.05,
            waiting: "paused: stopping"},
    resume: {path: "/mission/resume", done: (f) => f.mission && f.mission.state !== "PAUSED"},
    "doors-open": {path: "/body", body: {doors: "open"}, done: (f) => f.body && f.body.doors === "open"},
    "doors-close": {path: "/body", body: {doors: "close"}, done: (f) => f.body && f.body.doors === "closed"},
    "ramp-deploy": {path: "/body", body: {ramp: "deploy"}, done: (f) => f.body && f.body.ramp === "deployed"},
    "ramp-stow": {path: "/body", body: {ramp: "stow"}, done: (f) => f.body && f.body.ramp === "stowed"},
    rearm: {path: "/rearm", done: (f) => f.movement && !f.movement.latched},
    snapshot: {path: "/snapshots", body: {reason: "asked for on the operator page"},
               done: (f, before, reply) => savedSnapshots.has(reply.request_id)},
  };
  const savedSnapshots = new Set();   // request ids the recorder's `snapshot` events answered

  function say(state, message) {
    status.dataset.state = state;
    status.textContent = message;
  }

  function confirm(f) {
    if (!pending) return;
    if (pending.command.done(f, pending.before, pending.reply)) {
      say("confirmed", pending.name + ": confirmed by the vehicle after " +
          ((Date.now() - pending.since) / 1000).toFixed(1) + " s");
      pending = null;
    } else if (Date.now() - pending.since > 60000) {
      say("refused", pending.name + ": the vehicle has not confirmed it within 60 s");
      pending = null;
    }
  }

  for (const button of document.querySelectorAll("[data-command]")) {
    button.addEventListener("click", async () => {
      const name = button.dataset.command;
      const command = COMMANDS[name];
      const before = {goal: last && last.mission ? last.mission.goal_id : 0};
      say("sending", name + ": sending…");
      const options = {method: "POST"};
      if (command.body) {
        options.body = JSON.stringify(command.body);
        options.headers = {"Content-Type": "application/json"};
      }
      const r = await ARES.api(base + command.path, options);
      const j = await r.json().catch(() => ({}));
      if (!r.ok) {
        say("refused", name + ": " + (j.reason || j.detail || r.statusText));
        pending = null;
        return;
      }
      pending = {name, command, before, reply: j, since: Date.now()};
      say("pending", name + ": " + j.reason + " (waiting for the vehicle)");
      if (last) confirm(last);
    });
  }
});
