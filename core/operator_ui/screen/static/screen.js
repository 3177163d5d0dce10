// The station screen: renders the server's state (one object, sent whole on every change) and
// sends the operator's two actions.  No build step, no framework: a line PC runs it as served.
"use strict";
const $ = (id) => document.getElementById(id);
const token = new URLSearchParams(location.search).get("token");
let sphereDrawn = false;
let lastVersionShown = null;
window.__latencies = [];  // sample reaching the sequencer → sphere drawn (ms), read by the benchmark

function esc(text) {
  const d = document.createElement("div");
  d.textContent = text == null ? "" : String(text);
  return d.innerHTML;
}

function pct(x) { return x == null ? "—" : Math.round(x * 100) + "%"; }

const centresByCount = {};  // bin count → promise of the bins' centres, fetched once
let sphereShown = "";  // the bin count and hit set the sphere shows now

function binCentres(n) {
  if (!centresByCount[n]) {
    centresByCount[n] = fetch(`/api/bins/${n}` + (token ? `?token=${encodeURIComponent(token)}` : ""))
      .then((r) => r.json());
  }
  return centresByCount[n];
}

// Redraws only when the hit set changed: most updates at 200 samples/s hit no new bin, and a 3D
// redraw is the costliest thing the page does.  Returns whether the sphere changed.
function drawSphere(run, sides) {
  if (!run || !run.n_bins) {  // a new unit: no bins hit yet
    if (sphereDrawn) { Plotly.purge("sphere"); sphereDrawn = false; sphereShown = ""; }
    $("sphere").dataset.hit = "0";
    return false;
  }
  const bins = run.bins || [];
  const key = `${run.n_bins}:${bins.join(",")}`;
  if (key === sphereShown) { return false; }
  sphereShown = key;
  binCentres(run.n_bins).then((centres) => {
    if (sphereShown !== key) { return; }  // a newer state already took over
    const hit = new Set(bins);
    const colour = centres.map((_, i) => (hit.has(i) ? "#1a7f37" : "#d0d7de"));
    if (!sphereDrawn) {
      // the unit's axes are forward-right-down: drawn turned 180° about the nose (forward-left-up), so that
      // "bottom" is at the bottom of the picture, seen from behind, above and to the left
      const trace = { type: "scatter3d", mode: "markers", x: centres.map((c) => c[0]), y: centres.map((c) => -c[1]),
                      z: centres.map((c) => -c[2]), marker: { size: 9, color: colour }, hoverinfo: "skip" };
      const layout = { margin: { l: 0, r: 0, t: 0, b: 0 }, showlegend: false,
                       scene: { aspectmode: "cube", xaxis: { visible: false }, yaxis: { visible: false }, zaxis: { visible: false },
                                camera: { eye: { x: -1.5, y: 1.0, z: 0.9 } } } };
      // the same six words the coverage line names, where they are on the sphere
      const words = { type: "scatter3d", mode: "text", x: sides.map((w) => w.at[0] * 1.3),
                      y: sides.map((w) => -w.at[1] * 1.3), z: sides.map((w) => -w.at[2] * 1.3),
                      text: sides.map((w) => w.name), textfont: { size: rootPx(), color: "#1d1d1f" }, hoverinfo: "skip" };
      Plotly.newPlot("sphere", [trace, words], layout, { displayModeBar: false, responsive: true });
      sphereDrawn = true;
    } else {
      Plotly.restyle("sphere", { "marker.color": [colour] }, [0]);
    }
    $("sphere").dataset.hit = String(hit.size);
  });
  return true;
}

// The root font size (screen.css): 16 px on a laptop, up to 24 px on a full-HD monitor.
function rootPx() { return parseFloat(getComputedStyle(document.documentElement).fontSize) || 16; }

// The sphere takes the height the words under it leave on the screen, within 240–460 px (growing with
// the root font on a large screen): the sides still to turn must be on a short screen (a 1024×768 line
// PC) without scrolling — an operator two metres away cannot scroll — and their lines change as sides
// are covered.
const SPHERE_PX = { min: 240, max: 460 };
function fitSphere() {
  const sphere = $("sphere");
  const words = $("coverage-text").offsetHeight + $("missing").offsetHeight;
  const top = sphere.getBoundingClientRect().top + window.scrollY;
  const most = SPHERE_PX.max * rootPx() / 16;
  const below = rootPx();  // the page's bottom padding (main: 1em)
  const height = Math.round(Math.min(most, Math.max(SPHERE_PX.min, innerHeight - top - words - below)));
  if (Math.abs(sphere.offsetHeight - height) > 1) {
    sphere.style.height = `${height}px`;
    if (sphereDrawn) { Plotly.Plots.resize(sphere); }
  }
}
window.addEventListener("resize", fitSphere);

// The verdict is read from two metres, where nobody scrolls: when the details under the word and what
// to do with the unit (the cause, the cards per compass, the record) would run off the
// bottom of the screen, they are drawn smaller, down to half their size; the word, the serial and
// what to do keep theirs.
const DETAIL = { least: 0.5, step: 0.1 };
function fitVerdict() {
  const overlay = $("verdict");
  if (overlay.hidden) { return; }
  const shown = [...overlay.children].filter((e) => e.offsetParent !== null);
  if (!shown.length) { return; }
  const style = getComputedStyle(overlay);
  const room = innerHeight - (overlay.getBoundingClientRect().top + window.scrollY) - parseFloat(style.paddingTop)
    - parseFloat(style.paddingBottom) - rootPx();  // and the page's bottom padding (main: 1em)
  const needed = () => shown.at(-1).getBoundingClientRect().bottom - shown[0].getBoundingClientRect().top;
  let detail = 1;
  overlay.style.setProperty("--detail", "1");
  while (detail - DETAIL.step >= DETAIL.least - 1e-9 && needed() > room) {
    detail -= DETAIL.step;
    overlay.style.setProperty("--detail", detail.toFixed(2));
  }
}
window.addEventListener("resize", fitVerdict);

function slotPanel(slot, entry) {
  if (!entry) { return `<div class="slot empty" data-slot="${esc(slot.id)}"><h3>slot ${esc(slot.id)}</h3>no unit</div>`; }
  const v = entry.result;
  const run = entry.run;
  if (v) {
    const items = (v.items || []).map((m) => `<div>${esc(m.name)} ${esc(m.value)} ${esc(m.limit)} ${esc(m.verdict)}</div>`).join("");
    return `<div class="slot ${esc(v.verdict)}" data-slot="${esc(slot.id)}"><h3>slot ${esc(slot.id)} · ${esc(v.serial)}</h3>`
      + `<div class="word">${esc(v.verdict.toUpperCase())}</div><div class="action">${esc(v.action || "")}</div>`
      + `<div class="cause">${esc(v.cause || "")}</div>${items}</div>`;
  }
  const running = run.phases.find((p) => p.state === "running");
  $("progress").hidden = !run;  // idle: no empty bar
  const fraction = progressFraction(run);
  return `<div class="slot" data-slot="${esc(slot.id)}"><h3>slot ${esc(slot.id)} · ${esc(run.serial)} <small>${esc(run.part)}</small></h3>`
    + `<div class="phase">${esc(running ? running.name : "…")}${run.waiting ? ` · ${esc(run.waiting.what)} ${run.waiting.elapsed_s} s` : ""}</div>`
    + `<div class="attempt">${run.attempt ? `attempt ${run.attempt}` : ""}</div>`
    + `<div class="bar"><div style="width:${fraction * 100}%"></div></div>`
    + `<div>${esc(progressLabel(run))}</div>`
    + `<div class="prompt">${esc(promptOf(run))}</div></div>`;
}

// Progress toward the stop: coverage against its target where directions are judged (a determined
// tumble can end long before the most samples), else the sample count.
function progressFraction(run) {
  if (!run) { return 0; }
  if (stoppedNow(run)) { return 1; }
  // a wait before any reading (the unit warming up) fills the bar as it runs
  if (run.waiting && run.waiting.limit_s && !run.samples) { return Math.min(1, run.waiting.elapsed_s / run.waiting.limit_s); }
  if (run.n_bins && run.target) { return Math.min(1, run.coverage / run.target); }
  return run.target_samples ? Math.min(1, run.samples / run.target_samples) : 0;
}

// The words on the bar say what fills it: the coverage toward its target where directions are judged,
// else the readings toward the most the station takes ("400 readings (at most 600)" under a bar filled
// by coverage told the operator the wrong story).
function progressLabel(run) {
  if (!run) { return ""; }
  if (run.waiting && run.waiting.limit_s && !run.samples) { return `${run.waiting.what} ${run.waiting.elapsed_s} s`; }
  if (run.n_bins && run.target) {
    return `coverage ${pct(run.coverage)} of the ${pct(run.target)} needed` + (run.samples ? ` · ${run.samples} readings` : "");
  }
  return run.target_samples ? `${run.samples} of at most ${run.target_samples} readings` : "";
}

function stoppedNow(run) { return run && run.stopped && run.stopped.attempt === run.attempt; }

// Once the tumble of this attempt ended the operator is told so ("determined after 6 s — stop
// moving the unit") instead of the tumble prompt.
function promptOf(run) { return stoppedNow(run) ? run.stopped.line : (run ? run.prompt : ""); }

let slotInputsMade = false;
function renderSlots(s) {
  const slots = s.station.slots;
  if (!slotInputsMade) {
    slotInputsMade = true;
    $("start-form").hidden = true;
    $("slot-form").hidden = false;
    $("left").hidden = true;
    $("middle").hidden = true;
    $("slots").hidden = false;
    $("slot-inputs").innerHTML = slots.map((slot) =>
      `<label>${esc(slot.id)} <input data-slot="${esc(slot.id)}" placeholder="${esc(slot.part)}"></label>`).join(" ");
    const inputs = [...document.querySelectorAll("#slot-inputs input")];
    inputs.forEach((input, i) => input.addEventListener("keydown", (e) => {
      if (e.key === "Enter" && i < inputs.length - 1) { e.preventDefault(); inputs[i + 1].focus(); }
    }));
    inputs[0].focus();
  }
  // slot-start stays enabled while units run: a second load gets an answer, never silence
  $("slot-abort").disabled = !s.busy;
  $("slots").innerHTML = slots.map((slot) => slotPanel(slot, (s.slots || {})[slot.id])).join("");
  const r = s.round;
  $("round").textContent = r && r.moving ? `${r.motion} round ${r.number}: slots ${r.slots.join(", ")} sampling` : "";
  if (s.refusal && !s.busy) { $("form-error").textContent = s.refusal; }
}

function itemRows(items) {
  // what was measured in words first; the catalogue name small, for the technician
  return (items || []).map((m) => `<tr><td>${esc(m.label || m.name)}<br><small>${esc(m.name)}</small></td>`
    + `<td>${esc(m.value)}</td><td>${esc(m.limit)}</td><td>${esc(m.verdict)}</td><td>${esc(m.why)}</td></tr>`).join("");
}

// In a compass's card, whose title already names it: a line per measurement, its words then value,
// limits and verdict (a table's columns squeezed into a quarter of the screen ran to many lines).
function cardItems(items) {
  return items.map((m) => `<div class="item">${esc(m.label)}: <b>${esc(m.value)}</b> ${esc(m.limit)} ${esc(m.verdict)}`
    + `${m.why ? ` — ${esc(m.why)}` : ""} <small>${esc(m.name)}</small></div>`).join("");
}

// One cue per retry (per unit and attempt), where the browser allows sound: a page that has had a
// key press or a click may play it.  Kept in window.__cues so a test can see it was given.
const cued = new Set();
window.__cues = [];
function cue(key) {
  if (cued.has(key)) { return; }
  cued.add(key);
  window.__cues.push(key);
  try {
    const audio = new (window.AudioContext || window.webkitAudioContext)();
    [0, 0.25].forEach((at) => {
      const tone = audio.createOscillator();
      const gain = audio.createGain();
      tone.frequency.value = 660;
      gain.gain.value = 0.3;
      tone.connect(gain).connect(audio.destination);
      tone.start(audio.currentTime + at);
      tone.stop(audio.currentTime + at + 0.15);
    });
  } catch (e) { /* no audio device: the look alone tells */ }
}

// A scan refused while a unit runs ("… was not started: … finish or abort it first") says so until that
// unit's verdict is shown: then it is old news, and under a PASS it read like a second unit's refusal.
let refusedWhileBusy = false;
let shownBusy = false;
function forgetOldRefusal(s) {
  if (shownBusy && !s.busy && refusedWhileBusy) { $("form-error").textContent = ""; refusedWhileBusy = false; }
  shownBusy = Boolean(s.busy);
}

function render(s) {
  forgetOldRefusal(s);
  $("station-name").textContent = `${s.station.id} · line ${s.station.line}`;
  const f = s.field || {};
  let field = `field ${f.source || "—"}` + (f.field_ut != null ? ` ${f.field_ut} µT (${f.model})` : "");
  if (f.last_check) { field += `, fluxgate ${f.last_check.measured_ut} µT at ${f.last_check.at.slice(11, 19)}`; }
  $("field").textContent = field;
  const st = s.store || {};
  $("store").textContent = st.error ? `results store: ${st.error}`
    : `results: ${st.where || "—"}` + (st.queued ? ` — ${st.queued} QUEUED for forwarding` : "");

  const part = $("part");
  if (s.station.parts.length > 1 && part.options.length === 0) {
    for (const p of s.station.parts) { part.add(new Option(p, p, p === s.station.default_part, p === s.station.default_part)); }
    part.hidden = false;
  }
  // Start stays enabled while a unit runs: a second scan gets an answer, never silence
  $("abort").disabled = !s.busy;
  // a question the unit waits on (the propellers off before a motor test): above everything, yes or no
  const q = s.question;
  $("question").hidden = !q;
  $("question").dataset.id = q ? q.id : "";
  $("question-text").textContent = q ? (q.slot ? `slot ${q.slot}: ` : "") + q.text : "";

  const sh = s.shift || {};
  const units = sh.units || 0;
  $("shift-title").textContent = sh.word === "today" ? "Today" : "This shift";
  $("shift").textContent = `${units} unit${units === 1 ? "" : "s"}, first-pass yield ${pct(sh.fpy)}`;
  $("recent").innerHTML = (s.recent || []).map((r) => `<li class="${esc(r.verdict)}">${r.slot ? `${esc(r.slot)}: ` : ""}`
    + `${esc(r.serial)} ${esc(r.verdict.toUpperCase())} <small>${esc(r.part)}</small></li>`).join("");
  if (s.station.slots && s.station.slots.length) { renderSlots(s); return; }

  const run = s.run;
  // a station refusal (another screen or console holds the station, a fault before the first phase) is
  // not a unit's verdict: said where the scan is, with nothing recorded, the idle screen kept under it
  $("refusal").hidden = !(s.refusal && !s.busy);
  $("refusal-text").textContent = s.refusal || "";
  $("idle").hidden = Boolean(run) || s.busy;
  $("idle-what").textContent = s.station.serial_prompt;
  $("idle-shift").textContent = `${units} unit${units === 1 ? "" : "s"} ${sh.word || "this shift"}`
    + (sh.fpy != null ? `, first-pass yield ${pct(sh.fpy)}` : "");
  const last = (s.recent || [])[0];
  $("idle-last").textContent = last ? `last: ${last.serial} ${last.verdict.toUpperCase()}` : "";
  $("idle-last").className = last ? last.verdict : "";
  $("unit").textContent = run ? `${run.serial} · ${run.part}` : "";
  $("prompt").textContent = promptOf(run);
  // a turntable: the cradle's tilt asked for, drawn (side and rear views), while the operator sets it
  const tilt = run && run.tilt && !stoppedNow(run) && run.tilt.state !== "stalled" ? run.tilt : null;
  $("tilt").hidden = !tilt;
  if (tilt && $("tilt").dataset.shown !== tilt.svg) { $("tilt").innerHTML = tilt.svg; $("tilt").dataset.shown = tilt.svg; }
  $("tilt").classList.toggle("turning", Boolean(tilt && tilt.state === "turning"));
  $("attempt").textContent = run && run.attempt ? `attempt ${run.attempt}` : "";
  $("progress").hidden = !run;  // idle: no empty bar
  const fraction = progressFraction(run);
  $("progress-bar").style.width = `${fraction * 100}%`;
  $("progress-text").textContent = progressLabel(run);
  $("phases").innerHTML = run ? run.phases.map((p) =>
    `<li class="${esc(p.state)}">${esc(p.name)} — ${esc(p.state)}${p.duration_s != null ? ` (${p.duration_s} s)` : ""}`
    + `${p.state === "running" && run.waiting ? ` · ${esc(run.waiting.what)} ${run.waiting.elapsed_s} s` : ""}</li>`).join("") : "";
  const missing = run && run.n_bins && !stoppedNow(run) ? (run.missing || []) : [];
  $("coverage-text").textContent = run && run.n_bins ? `coverage ${pct(run.coverage)} (target ${pct(run.target)})` : "";
  $("missing").textContent = missing.length ? `${s.missing_words}: ${missing.join(", ")}` : "";
  // a second tumble looks and sounds different: the operator watching the unit knows the first was refused
  const retrying = Boolean(run && run.attempt > 1 && !stoppedNow(run));
  $("left").classList.toggle("retry", retrying);
  $("retry-banner").hidden = !retrying;
  if (retrying) {
    // the sides to turn are under the sphere: said twice, they pushed the prompt off a short screen
    $("retry-title").textContent = `${run.turns_unit === false ? "MEASURING AGAIN" : "TUMBLE AGAIN"} — attempt ${run.attempt}`;
    cue(`${run.serial}:${run.attempt}`);
  }
  // a coil's sphere shows the field directions applied; the words for turning the unit do not belong on it
  const sphereChanged = drawSphere(run, run && run.turns_unit === false ? [] : s.sides || []);
  fitSphere();

  const v = s.result;
  const overlay = $("verdict");
  if (v && !s.busy) {
    overlay.className = v.verdict;
    $("verdict-word").textContent = v.verdict.toUpperCase();
    $("verdict-serial").textContent = v.serial;
    $("verdict-part").textContent = v.part || "";
    $("verdict-action").textContent = v.action || "";
    // the cause once: a FAIL's first failed measurement is in the rows below, not repeated above them
    const repeated = (v.items || []).some((m) => v.cause && v.cause.startsWith(m.name));
    $("verdict-cause").textContent = repeated ? "" : (v.cause || "");
    const cards = v.sensors || [];
    // several magnetometers: a card per compass, each with its own verdict and failures, then the pairs'
    // agreement (the pairs that agree on one card)
    $("verdict-items").innerHTML = cards.length ? "" : itemRows(v.items);
    $("verdict-sensors").innerHTML = cards.map((c) => `<div class="sensor ${esc(c.verdict)}"><h3>${esc(c.title)}</h3>`
      + `<div class="word">${esc(c.verdict.toUpperCase())}</div><div>${esc(c.detail)}</div>`
      + cardItems(c.items) + "</div>").join("");
    // the parameter to set, the orientation found: small, below what the operator does with the unit
    $("verdict-technician").hidden = !v.technician;
    $("verdict-technician-text").textContent = v.technician || "";
    $("verdict-store").textContent = v.store ? `record: ${v.store}` : "";
    const link = $("verdict-report");
    link.hidden = !v.report;
    if (v.report) { link.href = `/reports/${encodeURIComponent(v.report)}`; }
    overlay.hidden = false;
    fitVerdict();
  } else {
    overlay.hidden = true;
  }
  if (run && run.progress_at_ms && run.progress_at_ms !== lastVersionShown) {
    const first = lastVersionShown === null;  // what the page found on opening is not a fresh sample
    lastVersionShown = run.progress_at_ms;
    if (!first) {  // the next frame starts once this one is painted
      requestAnimationFrame(() => window.__latencies.push({ ms: Date.now() - run.progress_at_ms, sphere: sphereChanged }));
    }
  }
}

// States arrive faster than a screen refreshes: keep the newest, draw it once per animation frame.
let newest = null;
function show(state) {
  const pending = newest !== null;
  newest = state;
  if (!pending) { requestAnimationFrame(() => { const s = newest; newest = null; render(s); }); }
}

function connect() {
  const events = new EventSource("/api/events" + (token ? `?token=${encodeURIComponent(token)}` : ""));
  events.addEventListener("state", (e) => { $("banner").hidden = true; show(JSON.parse(e.data)); });
  events.addEventListener("alive", () => { $("banner").hidden = true; });
  events.onopen = () => { $("banner").hidden = true; };
  events.onerror = () => { $("banner").hidden = false; };  // EventSource reconnects by itself
}

async function post(path, body) {
  const response = await fetch(path + (token ? `?token=${encodeURIComponent(token)}` : ""), {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body || {}) });
  const answer = await response.json().catch(() => ({}));
  $("form-error").textContent = response.ok ? "" : (answer.error || `error ${response.status}`);
  if (response.status === 409) { refusedWhileBusy = true; }
  return { ok: response.ok, busy: response.status === 409, slot: answer.slot };
}

// A scanner types its label and Enter into whatever field has the focus.  A scan that was not started
// must leave nothing for the next one to join: refused because a unit runs, the field is emptied (the
// refusal names the serial); refused by a rule, its text is selected, so the next scan replaces it and
// a person can still correct a typing slip.
$("start-form").addEventListener("submit", async (e) => {
  e.preventDefault();
  const field = $("serial");
  const serial = field.value.trim();
  const part = $("part").hidden ? null : $("part").value;
  const answer = await post("/api/start", { serial, part });
  field.focus();
  if (answer.ok || answer.busy) { field.value = ""; } else { field.select(); }
});
$("abort").addEventListener("click", () => { post("/api/abort"); $("serial").focus(); });
for (const [button, yes] of [["question-yes", true], ["question-no", false]]) {
  $(button).addEventListener("click", () => {
    post("/api/answer", { id: Number($("question").dataset.id), yes });
    $("serial").focus();
  });
}
$("slot-form").addEventListener("submit", async (e) => {
  e.preventDefault();
  const inputs = [...document.querySelectorAll("#slot-inputs input")];
  const serials = Object.fromEntries(inputs.map((i) => [i.dataset.slot, i.value.trim()]));
  const answer = await post("/api/start", { serials });
  if (answer.ok || answer.busy) {
    inputs.forEach((i) => { i.value = ""; });
    inputs[0].focus();
  } else {  // the slot the refusal names (a repeated or malformed label) is the one to scan again
    const named = inputs.find((i) => i.dataset.slot === answer.slot) || inputs[0];
    named.focus();
    named.select();
  }
});
$("slot-abort").addEventListener("click", () => { post("/api/abort"); });
connect();
