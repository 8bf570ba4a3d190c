// What the three pages share: the login and its token (renewed before it expires), calls to the
// API with the token, the live streams (server-sent events read with fetch, so that the token
// travels in the Authorization header and never in a URL), the map in the route's local frame.
"use strict";

const ARES = (() => {
  const API = "/api/v1";
  const KEY = "ares.session";
  let renewTimer = null;

  function session() {
    try { return JSON.parse(sessionStorage.getItem(KEY)); } catch (e) { return null; }
  }

  function save(s) {
    sessionStorage.setItem(KEY, JSON.stringify(s));
    scheduleRenew();
  }

  function scheduleRenew() {
    clearTimeout(renewTimer);
    const s = session();
    if (!s) return;
    const inMs = Math.max(s.expires - Date.now() - 60000, 5000);
    renewTimer = setTimeout(renew, inMs);
  }

  async function renew() {
    const s = session();
    if (!s) return;
    const r = await fetch(API + "/auth/renew", {method: "POST", headers: {Authorization: "Bearer " + s.token}});
    if (!r.ok) { logout("your session ended: log in again"); return; }
    const j = await r.json();
    save({...s, token: j.access_token, expires: Date.now() + j.expires_in * 1000});
  }

  async function login(user, password) {
    const body = new URLSearchParams({username: user, password: password, grant_type: "password"});
    const r = await fetch(API + "/auth/token", {method: "POST", body});
    const j = await r.json().catch(() => ({}));
    if (!r.ok) throw new Error(j.detail || r.statusText);
    const s = {token: j.access_token, role: j.role, user: user, expires: Date.now() + j.expires_in * 1000};
    save(s);
    return s;
  }

  function logout(why) {
    sessionStorage.removeItem(KEY);
    clearTimeout(renewTimer);
    if (why) sessionStorage.setItem("ares.why", why);
    location.reload();
  }

  async function api(path, options = {}) {
    const s = session();
    const headers = {...(options.headers || {}), Authorization: "Bearer " + (s ? s.token : "")};
    const r = await fetch(API + path, {...options, headers});
    if (r.status === 401) logout("your session ended: log in again");
    return r;
  }

  async function json(path, options = {}) {
    const r = await api(path, options);
    const j = await r.json().catch(() => ({}));
    if (!r.ok) throw new Error(j.detail || (r.status + " " + r.statusText));
    return j;
  }

  // A live stream: handlers.frame(data), handlers.events(list); reopened after a drop or the
  // token's expiry (with the renewed token; a refusal is retried after 5 s). Returns a function
  // that closes it.
  function stream(path, handlers) {
    let controller = null;
    let closed = false;
    async function open() {
      controller = new AbortController();
      let refused = false;
      try {
        const r = await api(path, {signal: controller.signal, headers: {Accept: "text/event-stream"}});
        if (!r.ok) {
          const j = await r.json().catch(() => ({}));
          refused = true;
          if (handlers.error) handlers.error(j.detail || r.statusText);
          throw new Error("stream refused");
        }
        if (handlers.open) handlers.open();
        const reader = r.body.getReader();
        const decoder = new TextDecoder();
        let buffer = "";
        for (;;) {
          const {value, done} = await reader.read();
          if (done) break;
          buffer += decoder.decode(value, {stream: true});
          let cut;
          while ((cut = buffer.indexOf("\n\n")) >= 0) {
            const block = buffer.slice(0, cut);
            buffer = buffer.slice(cut + 2);
            let event = "message", data = "";
            for (const line of block.split("\n")) {
              if (line.startsWith("event: ")) event = line.slice(7);
              else if (line.startsWith("data: ")) data += line.slice(6);
            }
            if (handlers[event]) handlers[event](JSON.parse(data || "null"));
          }
        }
      } catch (e) {
        if (closed) return;
      } finally {
        controller.abort();             // a handler's error must not leave the old request holding a slot
      }
      if (!refused && handlers.drop) handlers.drop();
      if (!closed) setTimeout(open, refused ? 5000 : 1000);
    }
    open();
    return () => { closed = true; if (controller) controller.abort(); };
  }

  // The page for `roles`: the login form until someone logs in; a refusal for another role.
  function page(roles, title, start) {
    const loginEl = document.getElementById("login");
    const refused = document.getElementById("refused");
    const app = document.getElementById("app");
    const who = document.getElementById("who");
    const why = sessionStorage.getItem("ares.why");
    sessionStorage.removeItem("ares.why");
    document.getElementById("logout").addEventListener("click", async () => {
      // the token refused from now on, not only forgotten here: a copy of it (a shared screen, a
      // proxy's log) is worth nothing after the logout
      // forgotten here first: a navigation before the revocation answers must not find it again
      const s = session();
      sessionStorage.removeItem(KEY);
      clearTimeout(renewTimer);
      if (s) {
        await fetch(API + "/auth/revoke", {method: "POST", headers: {Authorization: "Bearer " + s.token}})
          .catch(() => null);   // the server unreachable: the token still lapses at its expiry
      }
      logout();
    });
    const s = session();
    if (!s || s.expires < Date.now()) {
      loginEl.hidden = false;
      if (why) document.getElementById("login-error").textContent = why;
      document.getElementById("login-form").addEventListener("submit", async (ev) => {
        ev.preventDefault();
        const form = new FormData(ev.target);
        try {
          await login(form.get("username"), form.get("password"));
          location.reload();
        } catch (e) {
          document.getElementById("login-error").textContent = "login failed: " + e.message;
        }
      });
      return;
    }
    who.textContent = s.user + " (" + s.role + ")";
    document.getElementById("logout").hidden = false;
    if (!roles.includes(s.role)) {
      refused.hidden = false;
      refused.querySelector(".why").textContent =
        "The " + title + " page is for the " + roles.join(" or ") + " role; you are logged in as " + s.user +
        " (" + s.role + ").";
      return;
    }
    scheduleRenew();
    app.hidden = false;
    start(s);
  }

  // Values into the elements that name them: data-field="mission.state" shows frame.mission.state.
  function fill(root, data) {
    for (const el of root.querySelectorAll("[data-field]")) {
      let v = data;
      for (const part of el.dataset.field.split(".")) v = v == null ? null : v[part];
      const digits = el.dataset.digits;
      const text = v == null ? "–" : (digits !== undefined && typeof v === "number" ? v.toFixed(+digits) : String(v));
      if (el.textContent !== text) el.textContent = text;
      el.dataset.value = v == null ? "" : String(v);
    }
  }

  // Leaflet in the route's local frame (metres, x east, y north): [y, x] as [lat, lng].
  function map(element) {
    if (typeof L === "undefined") {
      element.textContent = "The map library is missing (run scripts/setup.sh: npm installs it).";
      return null;
    }
    const m = L.map(element, {crs: L.CRS.Simple, minZoom: -4, maxZoom: 4, zoomSnap: 0.25, attributionControl: false,
                              preferCanvas: true});
    return m;
  }

  function ll(x, y) { return [y, x]; }

  // The route and its POIs on the map, fitted to view; POI names always shown or on hover.
  function drawRoute(m, route, labelled) {
    const line = L.polyline(route.x.map((x, i) => ll(x, route.y[i])), {color: "#52606d", weight: 3}).addTo(m);
    m.fitBounds(line.getBounds(), {padding: [10, 10]});
    for (const poi of route.pois) {
      L.circleMarker(ll(poi.x, poi.y), {radius: labelled ? 6 : 5, color: "#1d3557", fillOpacity: 1})
        .bindTooltip(text("span", poi.name), {permanent: labelled, direction: "right"}).addTo(m);
    }
  }

  function text(tag, content, cls) {
    const el = document.createElement(tag);
    el.textContent = content;
    if (cls) el.className = cls;
    return el;
  }

  function clock(t) { return new Date(t).toLocaleTimeString(); }

  return {api, json, stream, page, fill, map, ll, drawRoute, text, clock, session};
})();
