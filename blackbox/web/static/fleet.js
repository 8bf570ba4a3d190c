// The fleet page: every vehicle on the router on one map, live; the events of all of them; and
// the vehicles late between two points of interest (the gateway times each leg against the
// same leg's past runs, else the speed profile's expected time).
"use strict";

ARES.page(["fleet"], "fleet", async () => {
  const route = await ARES.json("/route");
  const lagEl = document.getElementById("lag");
  const table = document.getElementById("vehicles");
  const lateEl = document.getElementById("late");
  const lateNone = document.getElementById("late-none");
  const eventsEl = document.getElementById("events");
  const markers = new Map();
  const map = ARES.map(document.getElementById("map"));
  if (map) ARES.drawRoute(map, route, false);

  const fmt = (v, d) => (v == null ? "–" : typeof v === "number" ? v.toFixed(d) : String(v));

  function draw(vehicles) {
    const seen = new Set();
    for (const v of vehicles) {
      seen.add(v.vehicle_id);
      if (!map || !v.pose) continue;
      let m = markers.get(v.vehicle_id);
      if (!m) {
        m = L.circleMarker(ARES.ll(v.pose.x, v.pose.y), {radius: 8, color: "#b42318", fillOpacity: 0.9})
          .bindTooltip(ARES.text("span", v.vehicle_id), {permanent: true, direction: "top"}).addTo(map);
        markers.set(v.vehicle_id, m);
      }
      m.setLatLng(ARES.ll(v.pose.x, v.pose.y));
      m.setStyle({color: v.reachable === false ? "#667085" : v.leg && v.leg.late ? "#b42318" : v.awareness && v.awareness.level ? "#b54708" : "#1e7b34"});
    }
    for (const [id, m] of markers) if (!seen.has(id)) { m.remove(); markers.delete(id); }
  }

  function rows(vehicles) {
    table.replaceChildren();
    const head = document.createElement("tr");
    for (const h of ["vehicle", "speed m/s", "mode", "mission", "POI", "awareness", "controller", "leg", "since / expected s"]) head.append(ARES.text("th", h));
    table.append(head);
    for (const v of vehicles) {
      const tr = document.createElement("tr");
      tr.dataset.vehicle = v.vehicle_id;
      const leg = v.leg || {};
      // a cut link: the fleet has heard nothing from the vehicle for silent_s (the rest is its last state)
      const name = v.reachable === false ? v.vehicle_id + " (unreachable " + fmt(v.silent_s, 0) + " s)" : v.vehicle_id;
      tr.dataset.reachable = String(v.reachable !== false);
      tr.append(ARES.text("td", name, v.reachable === false ? "late" : ""), ARES.text("td", fmt(v.speed_mps, 2)), ARES.text("td", fmt(v.mode)),
                ARES.text("td", v.mission ? v.mission.state : "–"), ARES.text("td", v.mission ? fmt(v.mission.poi) : "–"),
                ARES.text("td", v.awareness ? String(v.awareness.level) : "–", v.awareness ? "level-" + v.awareness.level : ""),
                ARES.text("td", fmt(v.controller)),
                ARES.text("td", leg.to ? (leg.from || "start") + " → " + leg.to : "–"),
                ARES.text("td", fmt(leg.since_s, 0) + " / " + fmt(leg.expected_s, 0), leg.late ? "late" : ""));
      table.append(tr);
    }
  }

  function late(vehicles) {
    lateEl.replaceChildren();
    const list = vehicles.filter((v) => v.leg && v.leg.late);
    for (const v of list) {
      const l = v.leg;
      lateEl.append(ARES.text("li", v.vehicle_id + ": " + (l.from || "start") + " → " + l.to + ", " + l.since_s.toFixed(0) +
                              " s since the last POI, expected " + l.expected_s.toFixed(0) + " s (" + l.expected_from + ")", "late"));
    }
    lateNone.hidden = list.length > 0;
  }

  ARES.stream("/live/fleet", {
    frame(f) {
      lagEl.textContent = "live · " + f.vehicles.length + " vehicles";
      draw(f.vehicles);
      rows(f.vehicles);
      late(f.vehicles);
    },
    events(list) {
      for (const e of list) eventsEl.prepend(ARES.text("li", ARES.clock(e.wall_ms) + "  " + e.vehicle_id + " · " + e.source +
                                                       ": " + e.message, e.level));
      while (eventsEl.children.length > 200) eventsEl.lastChild.remove();
    },
    drop() { lagEl.textContent = "reconnecting…"; },
    error(why) { lagEl.textContent = "live refused: " + why; },
  });
});
