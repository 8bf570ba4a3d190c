// The black box page (auditors): a vehicle and a window inside the last 7 days, the fields to
// see, a table and plots over time, and the window exported as CSV or JSON lines. Everything
// comes from the REST API the page's token may read; the export is the API's own file. The window's
// incident snapshots (the bus around an emergency stop, a takeover, ...) are listed with their
// cause and downloaded as the API streams them.
"use strict";

ARES.page(["auditor"], "black box", async () => {
  const FIELDS = ["speed_mps", "steering_wheel_deg", "command", "scores", "controller", "awareness_level", "mode",
                  "mission_state", "position", "sensors", "processes", "events"];
  const DEFAULT = ["speed_mps", "steering_wheel_deg", "command", "scores", "controller", "awareness_level", "mode"];
  const RETENTION_MS = 7 * 24 * 3600 * 1000;
  const MAX_PAGES = 20;                 // 20,000 records: five and a half hours of seconds
  const select = document.getElementById("vehicle-select");
  const startEl = document.getElementById("start");
  const endEl = document.getElementById("end");
  const statusEl = document.getElementById("query-status");
  const fieldsEl = document.getElementById("fields");
  const table = document.getElementById("records");
  const plotsEl = document.getElementById("plots");

  for (const f of FIELDS) {
    const label = document.createElement("label");
    const box = document.createElement("input");
    box.type = "checkbox"; box.value = f; box.checked = DEFAULT.includes(f); box.name = "field";
    label.append(box, document.createTextNode(f));
    fieldsEl.append(label);
  }

  // datetime-local is the browser's local time; the API wants UTC with its offset
  const toInput = (ms) => { const d = new Date(ms - new Date(ms).getTimezoneOffset() * 60000);
                            return d.toISOString().slice(0, 19); };
  const fromInput = (value) => new Date(value).toISOString();

  const vehicles = (await ARES.json("/vehicles")).vehicles;
  for (const v of vehicles) select.append(new Option(v.vehicle_id, v.vehicle_id));
  function defaultWindow() {
    const v = vehicles.find((x) => x.vehicle_id === select.value);
    const end = v && v.last_seen ? Date.parse(v.last_seen) + 1000 : Date.now();
    endEl.value = toInput(end);
    startEl.value = toInput(end - 10 * 60 * 1000);
  }
  select.addEventListener("change", defaultWindow);
  defaultWindow();

  function window_() {
    const start = Date.parse(fromInput(startEl.value)), end = Date.parse(fromInput(endEl.value));
    if (!(end > start)) throw new Error("the window's end must come after its start");
    if (start < Date.now() - RETENTION_MS) throw new Error("the black box keeps 7 days: start within them");
    return {vehicle: select.value, start: new Date(start).toISOString(), end: new Date(end).toISOString()};
  }
  const chosen = () => [...fieldsEl.querySelectorAll("input:checked")].map((b) => b.value);

  async function show(ev) {
    if (ev) ev.preventDefault();
    let w;
    try { w = window_(); } catch (e) { statusEl.textContent = e.message; statusEl.dataset.state = "refused"; return; }
    const fields = chosen();
    statusEl.dataset.state = "pending";
    statusEl.textContent = "reading…";
    const rows = [];
    let total = 0;
    for (let page = 1; page <= MAX_PAGES; page++) {
      const q = new URLSearchParams({start: w.start, end: w.end, page: page, page_size: 1000});
      if (fields.length) q.set("fields", fields.join(","));
      let j;
      try { j = await ARES.json("/vehicles/" + encodeURIComponent(w.vehicle) + "/records?" + q); }
      catch (e) { statusEl.textContent = e.message; statusEl.dataset.state = "refused"; return; }
      total = j.total;
      rows.push(...j.records);
      statusEl.textContent = "reading… " + rows.length + " of " + total;
      if (rows.length >= total || j.records.length === 0) break;
    }
    statusEl.dataset.state = "confirmed";
    statusEl.textContent = rows.length + " records" + (rows.length < total ? " (the first " + rows.length +
                           " of " + total + ": narrow the window to see the rest)" : "");
    statusEl.dataset.count = String(rows.length);
    render(rows, fields);
    plot(rows, fields);
    snapshots(w);
  }

  const snapshotsEl = document.getElementById("snapshots");
  const snapshotsStatus = document.getElementById("snapshots-status");
  async function snapshots(w) {
    const q = new URLSearchParams({start: w.start, end: w.end, page_size: 1000});
    let j;
    try { j = await ARES.json("/vehicles/" + encodeURIComponent(w.vehicle) + "/snapshots?" + q); }
    catch (e) { snapshotsStatus.textContent = e.message; return; }
    snapshotsEl.replaceChildren();
    const head = snapshotsEl.insertRow();
    for (const h of ["time", "cause", "covers (stack s)", "size", ""]) head.append(Object.assign(document.createElement("th"), {textContent: h}));
    for (const s of j.snapshots) {
      const row = snapshotsEl.insertRow();
      const d = s.data;
      for (const text of [s.time, d.cause, Number(d.from_t).toFixed(1) + " – " + Number(d.to_t).toFixed(1),
                          (Number(d.bytes) / 1e6).toFixed(1) + " MB"]) row.insertCell().textContent = text;
      const cell = row.insertCell();
      if (s.available) {
        const b = Object.assign(document.createElement("button"), {type: "button", textContent: "Download"});
        b.addEventListener("click", () => download(s.download, String(d.file)));
        cell.append(b);
      } else cell.textContent = "no longer kept";
    }
    snapshotsStatus.textContent = j.snapshots.length + " snapshot" + (j.snapshots.length === 1 ? "" : "s") + " in the window";
    snapshotsStatus.dataset.count = String(j.snapshots.length);
  }

  async function download(path, name) {
    const r = await ARES.api(path.replace(/^\/api\/v1/, ""));
    if (!r.ok) { const j = await r.json().catch(() => ({})); snapshotsStatus.textContent = "download: " + (j.detail || r.status); return; }
    const url = URL.createObjectURL(await r.blob());
    const a = document.createElement("a");
    a.href = url; a.download = name;
    document.body.append(a); a.click(); a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 10000);
    snapshotsStatus.textContent = "downloaded " + name;
  }

  function flat(record, fields) {
    const out = {time: record.time};
    for (const f of fields) {
      const v = record[f];
      if (v && typeof v === "object" && f === "scores") for (const k in v) out["score." + k] = v[k];
      else if (v && typeof v === "object" && f === "position") { out.x = v.x; out.y = v.y; out.lat = v.lat; out.lon = v.lon; }
      else if (v && typeof v === "object") out[f] = JSON.stringify(v);
      else out[f] = v;
    }
    return out;
  }

  function render(rows, fields) {
    table.replaceChildren();
    const flatRows = rows.slice(0, 2000).map((r) => flat(r, fields));
    const columns = [...new Set(flatRows.flatMap((r) => Object.keys(r)))];
    const head = document.createElement("tr");
    for (const c of columns) head.append(ARES.text("th", c));
    table.append(head);
    for (const r of flatRows) {
      const tr = document.createElement("tr");
      for (const c of columns) {
        const v = r[c];
        tr.append(ARES.text("td", v == null ? "" : typeof v === "number" ? String(+v.toFixed(4)) : String(v)));
      }
      tr.dataset.time = r.time;
      table.append(tr);
    }
  }

  // categorical fields are plotted as the index of their value, the legend naming each
  function series(rows, get) {
    const values = rows.map(get);
    const labels = [...new Set(values.filter((v) => typeof v === "string"))];
    return {data: values.map((v) => (typeof v === "string" ? labels.indexOf(v) : v == null ? null : v)), labels};
  }

  function plot(rows, fields) {
    plotsEl.replaceChildren();
    if (typeof uPlot === "undefined") { plotsEl.textContent = "The plot library is missing (scripts/setup.sh)."; return; }
    const t = rows.map((r) => Date.parse(r.time) / 1000);
    const groups = [];
    if (fields.includes("speed_mps")) groups.push({title: "speed (m/s)", s: {speed: (r) => r.speed_mps}});
    if (fields.includes("steering_wheel_deg")) groups.push({title: "steering wheel (°)", s: {steering: (r) => r.steering_wheel_deg}});
    if (fields.includes("command")) {  // what was asked beside what was done: speed and steering tracking
      const c = (r) => r.command || {};
      groups.push({title: "speed asked and driven (m/s)", s: {driven: (r) => r.speed_mps, commanded: (r) => c(r).commanded_speed_mps,
                                                             controller: (r) => c(r).controller_speed_mps, target: (r) => c(r).target_speed_mps}});
      groups.push({title: "curvature asked (1/m)", s: {commanded: (r) => c(r).commanded_curvature, controller: (r) => c(r).controller_curvature}});
    }
    if (fields.includes("scores")) {
      const names = [...new Set(rows.flatMap((r) => Object.keys(r.scores || {})))];
      groups.push({title: "scores", s: Object.fromEntries(names.map((n) => [n, (r) => (r.scores || {})[n]]))});
    }
    for (const f of ["controller", "awareness_level", "mode", "mission_state"]) {
      if (fields.includes(f)) groups.push({title: f, s: {[f]: (r) => r[f]}});
    }
    const colours = ["#1d3557", "#b42318", "#1e7b34", "#b54708", "#2e90fa", "#7a5af8"];
    const width = Math.max(plotsEl.clientWidth - 10, 300);
    for (const g of groups) {
      const built = Object.entries(g.s).map(([name, get]) => ({name, ...series(rows, get)}));
      const div = document.createElement("div");
      div.className = "plot";
      plotsEl.append(div);
      const title = g.title + built.filter((b) => b.labels.length).map((b) => "  [" + b.labels.map((l, i) => i + " " + l).join(", ") + "]").join("");
      new uPlot({title, width, height: 170, series: [{}, ...built.map((b, i) => ({label: b.name, stroke: colours[i % colours.length], width: 1.5}))],
                 scales: {x: {time: true}}}, [t, ...built.map((b) => b.data)], div);
    }
  }

  async function exportAs(format) {
    let w;
    try { w = window_(); } catch (e) { statusEl.textContent = e.message; return; }
    const q = new URLSearchParams({start: w.start, end: w.end, format});
    const r = await ARES.api("/vehicles/" + encodeURIComponent(w.vehicle) + "/export?" + q);
    if (!r.ok) { const j = await r.json().catch(() => ({})); statusEl.textContent = "export: " + (j.detail || r.status); return; }
    const name = (/filename="([^"]+)"/.exec(r.headers.get("Content-Disposition") || "") || [])[1] || "export." + format;
    const url = URL.createObjectURL(await r.blob());
    const a = document.createElement("a");
    a.href = url; a.download = name;
    document.body.append(a); a.click(); a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 10000);
    statusEl.textContent = "exported " + name;
  }

  document.getElementById("query").addEventListener("submit", show);
  document.getElementById("export-csv").addEventListener("click", () => exportAs("csv"));
  document.getElementById("export-jsonl").addEventListener("click", () => exportAs("jsonl"));
  if (select.value) show();
});
