// "The line now": one tile per station, redrawn whenever the store says a unit was recorded.
const $ = (id) => document.getElementById(id);
const esc = (s) => String(s == null ? "" : s).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c]));
const pct = (f) => (f == null ? "—" : `${Math.round(f * 100)}%`);
const token = new URLSearchParams(location.search).get("token");
window.__shown = 0;  // how many times the tiles were drawn (a test waits for the next one)

function ago(seconds) {
  if (seconds < 120) { return `${Math.round(seconds)} s`; }
  if (seconds < 7200) { return `${Math.round(seconds / 60)} min`; }
  return `${(seconds / 3600).toFixed(1)} h`;
}

function clock(iso) { return iso ? new Date(iso).toLocaleTimeString([], { hour: "2-digit", minute: "2-digit", hourCycle: "h23" }) : ""; }

// the field reference as the station's last unit met it: the live fluxgate's last check, else the model alone
function field(f) {
  if (!f) { return ""; }
  const model = `${esc(f.model)} ${Number(f.field_ut).toFixed(2)} µT`;
  const c = f.last_check;
  return `<div class="field">field: ${model}`
    + (c ? ` · checked ${Number(c.measured_ut).toFixed(2)} µT at ${clock(c.at)}, before the batch's unit ${c.after_units + 1}` : " · no live check")
    + `</div>`;
}

// what the station's outbox still held when it last reached this store (no row: it writes here directly)
function outbox(o) {
  if (!o) { return ""; }
  const when = `reported ${clock(o.reported)}`;
  return o.queued
    ? `<div class="outbox queued">outbox: ${o.queued} record${o.queued === 1 ? "" : "s"} queued since ${clock(o.oldest)} · ${when}</div>`
    : `<div class="outbox">outbox: empty · ${when}</div>`;
}

function tile(t, word) {
  const testing = t.testing.length
    ? t.testing.map((c) => `<div class="testing">${c.slot ? `slot ${esc(c.slot)}: ` : ""}testing ${esc(c.serial)}</div>`).join("")
    : `<div class="idle">no unit under test</div>`;
  const recent = t.recent.map((r) => `<li class="${esc(r.verdict)}"><a href="/unit?serial=${encodeURIComponent(r.serial)}">`
    + `${esc(r.serial)}</a> ${esc(r.verdict.toUpperCase())}${r.slot ? ` <small>slot ${esc(r.slot)}</small>` : ""}</li>`).join("");
  const silent = t.silent ? `<div class="silent">SILENT ${ago(t.silent_s)} — its usual gap is ${ago(t.usual_gap_s)}</div>` : "";
  const slot = t.slot ? ` · slot ${esc(t.slot)}` : "";
  return `<section class="tile${t.silent ? " flagged" : ""}" data-station="${esc(t.station_id)}"`
    + `${t.slot ? ` data-slot="${esc(t.slot)}"` : ""}>`
    + `<h2>${esc(t.station_id)}${slot} <small>line ${esc(t.line)}</small></h2>${silent}${testing}`
    + `<div class="figures"><span class="units">${t.units} unit${t.units === 1 ? "" : "s"} ${esc(word)}</span>`
    + ` · first-pass yield <b>${pct(t.fpy)}</b>`
    + (t.per_hour != null ? ` · ${t.per_hour.toFixed(1)} units/h` : "") + `</div>`
    + `<ol class="recent">${recent}</ol>${field(t.field)}${outbox(t.outbox)}`
    + `<a class="process" href="/process?station=${encodeURIComponent(t.station_id)}">its process</a></section>`;
}

function show(line) {
  $("when").textContent = `${line.shift_word} from ${line.shift_start.slice(11, 16)} · ${line.now.slice(11, 19)}`;
  $("where").textContent = line.store;
  $("empty").hidden = line.stations.length > 0;
  $("tiles").innerHTML = line.stations.map((t) => tile(t, line.shift_word)).join("");
  window.__shown += 1;
}

function connect() {
  const events = new EventSource("/api/events" + (token ? `?token=${encodeURIComponent(token)}` : ""));
  events.addEventListener("line", (e) => { $("banner").hidden = true; show(JSON.parse(e.data)); });
  events.addEventListener("alive", () => { $("banner").hidden = true; });
  events.onerror = () => { $("banner").hidden = false; };  // EventSource reconnects by itself
}
connect();
