// The Scan page: start/stop a scan, its tracking state, bands, breathing traces, 6-DOF, frames, alerts
// (a banner and a sound until acknowledged), the summary and the motion analysis. No figure without its
// state: a figure that is not known now says NOT KNOWN, never shown as if still.
"use strict";
(function () {
  const root = document.getElementById("scan");
  const token = root.dataset.token;
  const $ = (id) => document.getElementById(id);
  const WORDS = { TRACKING: "TRACKING", REFERENCE: "REFERENCE (learning)", "NOT TRACKING": "NOT TRACKING",
                  OFF: "NOT TRACKING" };
  const PHASES = { idle: "NO SCAN", starting: "STARTING", running: "RECORDING", stopping: "STOPPING",
                   stopped: "STOPPED", failed: "NOT STARTED" };
  const hhmmss = window.vtsClock.time;
  const num = (v, d = 1) => (v === null || v === undefined ? "–" : v.toFixed(d));
  let last = null;            // the last scan state
  let lastEvent = 0;
  // what the benchmark reads: seconds from a frame's arrival / an alert's arrival to it being shown
  window.vtsScan = { frameDelays: [], alertDelays: [], shownAlerts: {} };

  function post(url, body) {
    return fetch(url, { method: "POST", headers: { "Content-Type": "application/json", "X-Console-Token": token },
                        body: JSON.stringify(body || {}) })
      .then((r) => r.json().then((d) => { if (!r.ok) throw new Error(d.error || `HTTP ${r.status}`); return d; }))
      .then((d) => { $("message").textContent = ""; return d; })
      .catch((e) => { $("message").textContent = e.message; });
  }
  $("start").addEventListener("click", () => {
    unlockSound();
    post("/scan/start", { reference_s: $("reference").value || 10, duration_s: $("duration").value || null });
  });
  $("stop").addEventListener("click", () => post("/scan/stop"));
  $("analyse").addEventListener("click", () => post("/scan/analyse"));
  document.addEventListener("click", unlockSound);

  // -- the alarm: a beep every 1.5 s while an alert is not acknowledged ---------------------------------
  let audio = null;
  function unlockSound() {
    try {
      if (!audio) audio = new (window.AudioContext || window.webkitAudioContext)();
      if (audio.state === "suspended") audio.resume();
    } catch (e) { audio = null; }
  }
  function beep() {
    const box = $("alerts");
    unlockSound();
    if (!audio || audio.state !== "running") { box.dataset.sound = "blocked"; return; }
    const o = audio.createOscillator(), g = audio.createGain();
    o.type = "square"; o.frequency.value = 880; g.gain.value = 0.25;
    o.connect(g); g.connect(audio.destination);
    o.start(); o.stop(audio.currentTime + 0.35);
    box.dataset.sound = "played";
    box.dataset.beeps = String(Number(box.dataset.beeps) + 1);
  }
  setInterval(() => { if (document.querySelector(".alert:not(.acked)")) beep(); }, 1500);

  function showAlerts(alerts) {
    const box = $("alerts");
    let fresh = false;
    for (const a of alerts) {
      if (box.dataset.scan !== a.scan) { box.innerHTML = ""; box.dataset.scan = a.scan; }   // a new scan's alerts
      let el = box.querySelector(`.alert[data-alert="${a.id}"]`);
      if (!el) {
        el = document.createElement("div");
        el.className = "alert"; el.dataset.alert = a.id; el.dataset.kind = a.kind;
        el.innerHTML = '<span class="text"></span><span class="who"></span><button type="button">Acknowledge</button>';
        el.querySelector(".text").textContent = `${hhmmss(a.raised)} ${a.text}`;
        el.querySelector("button").addEventListener("click", () => post(`/scan/alert/${a.id}/ack`).then((d) => d && showAlerts([d])));
        box.prepend(el);
        window.vtsScan.shownAlerts[a.id] = Date.now() / 1000;
        window.vtsScan.alertDelays.push(Date.now() / 1000 - a.raised);
        fresh = true;
      }
      if (a.acked_by && !el.classList.contains("acked")) {
        el.classList.add("acked");
        el.dataset.ackedBy = a.acked_by;
        el.querySelector(".who").textContent = `acknowledged by ${a.acked_by} at ${hhmmss(a.acked_at)}`;
        el.querySelector("button").remove();
      }
    }
    if (fresh) beep();
  }

  // -- the live picture of each recorded camera (the Room page's way: one fetch in flight) -----------------
  const cams = {};
  document.querySelectorAll("figure.cam").forEach((el) => {
    cams[el.dataset.camera] = { name: el.dataset.camera, el, img: el.querySelector("img"), pic: el.querySelector(".pic"),
                                want: null, shown: null, arrival: null, busy: false, url: null };
  });
  const PICTURE_EVERY_MS = 500;   // at most 2 pictures a second per camera: a thumbnail, not the Room's view
  function pump(c) {
    if (c.busy || c.want === null || c.want === c.shown) return;
    const wait = PICTURE_EVERY_MS - (Date.now() - (c.fetched || 0));
    if (wait > 0) { if (!c.timer) c.timer = setTimeout(() => { c.timer = null; pump(c); }, wait); return; }
    c.busy = true; c.fetched = Date.now();
    fetch(`/frame/${encodeURIComponent(c.name)}`, { cache: "no-store" })
      .then((r) => {
        if (!r.ok) throw new Error(`HTTP ${r.status}`);
        const seq = Number(r.headers.get("X-Frame-Seq")), arrival = Number(r.headers.get("X-Frame-Arrival"));
        return r.blob().then((b) => ({ b, seq, arrival }));
      })
      .then(({ b, seq, arrival }) => new Promise((resolve, reject) => {
        const url = URL.createObjectURL(b);
        c.img.onload = () => {
          if (c.url) URL.revokeObjectURL(c.url);
          c.url = url; c.shown = seq; c.arrival = arrival; c.img.dataset.seq = String(seq);
          const d = window.vtsScan.frameDelays;
          if (d.length < 100000) d.push(Date.now() / 1000 - arrival);
          resolve();
        };
        c.img.onerror = () => { URL.revokeObjectURL(url); reject(new Error("not a picture")); };
        c.img.src = url;
      }))
      .then(() => { c.busy = false; pump(c); })
      .catch(() => { c.busy = false; setTimeout(() => pump(c), 500); });
  }

  // -- the state --------------------------------------------------------------------------------------------
  function showStatus(s) {
    const live = s.live, box = $("status");
    let st = "", word = "NOT TRACKING", reason = "no scan running";
    if (s.phase === "starting") { reason = "starting: checking the cameras"; }
    else if (live && (s.phase === "running" || s.phase === "stopping")) {
      st = live.status || "NOT TRACKING"; word = WORDS[st] || st;
      reason = live.reason || (st === "TRACKING" ? `tracked; figures ${num(live.age_s)} s old` : "");
      if (st !== "TRACKING" && live.for_s !== null) word += ` ${num(live.for_s)} s`;
      if (st === "REFERENCE" && live.note) reason = live.note;
    } else if (s.phase === "running") { reason = "live tracking not started"; }
    else if (s.phase === "stopped") { reason = "the scan has stopped: nothing is tracked now"; }
    box.className = "status st-" + (st ? st.replace(/ /g, "") : "none");
    box.dataset.status = st; root.dataset.status = st;
    box.querySelector(".word").textContent = word;
    box.querySelector(".reason").textContent = reason;
  }

  function showSix(s) {
    const live = s.live, t = $("six"), tds = t.querySelectorAll("tbody td:not(.known)");
    const known = !!(live && live.six_known && s.phase === "running");
    const six = live && live.six_dof;
    tds.forEach((td, i) => { td.textContent = six ? (i < 3 ? num(six[i]) : num(six[i], 2)) : "–"; });
    t.dataset.known = known ? "yes" : "no";
    const k = t.querySelector(".known");
    k.className = "known" + (known ? "" : " unknown");
    k.textContent = known ? `known (TRACKING): ${num(live.move_mm)} mm, ${num(live.turn_deg, 2)} deg, ${live.state}` :
      six ? `NOT KNOWN now: last pose ${num(live.age_s)} s ago; motion since then not known` : "NOT KNOWN: no pose yet";
  }

  function trace(points, svg) {
    const ns = "http://www.w3.org/2000/svg";
    while (svg.firstChild) svg.removeChild(svg.firstChild);
    const vals = points.filter((p) => p[1] !== null).map((p) => p[1]);
    svg.dataset.points = String(vals.length);
    if (!vals.length) return;
    const end = points[points.length - 1][0];
    let lo = Math.min(...vals), hi = Math.max(...vals);
    if (hi - lo < 1) { const m = (hi + lo) / 2; lo = m - 0.5; hi = m + 0.5; }
    svg.setAttribute("viewBox", `-30 ${-hi} 30 ${hi - lo}`);     // x: seconds before now; y: mm (up)
    svg.setAttribute("preserveAspectRatio", "none");
    let run = [];
    const flush = () => {
      if (run.length > 1) {
        const pl = document.createElementNS(ns, "polyline");
        pl.setAttribute("points", run.join(" "));
        svg.appendChild(pl);
      }
      run = [];
    };
    for (const [t, v] of points) {
      if (v === null) flush(); else run.push(`${(t - end).toFixed(3)},${(-v).toFixed(3)}`);
    }
    flush();
    svg.dataset.range = `${lo.toFixed(1)}..${hi.toFixed(1)} mm`;
  }

  function showBands(s) {
    const live = s.live, box = $("bands");
    if (!live || !live.bands || !live.bands.length) {
      box.innerHTML = `<p class="small">${live && live.phase === "reference" ? "learning the reference: the bands appear once it is learned" :
        "the bands appear once the reference is learned"}</p>`;
      return;
    }
    const now = s.phase === "running" && live.status === "TRACKING";
    for (const b of live.bands) {
      let el = box.querySelector(`.band[data-band="${b.band}"]`);
      if (!el) {
        if (box.querySelector("p")) box.innerHTML = "";
        el = document.createElement("div");
        el.className = "band"; el.dataset.band = b.band;
        el.innerHTML = '<div class="figs"></div><svg class="trace" xmlns="http://www.w3.org/2000/svg"></svg>';
        box.appendChild(el);
      }
      const known = now && b.known;
      el.dataset.known = known ? "yes" : "no";
      el.dataset.rate = b.rate_per_min === null ? "" : String(b.rate_per_min);
      const d = b.displacement_mm || [];
      el.querySelector(".figs").innerHTML = "";
      const lines = [`<b>Band ${b.band}</b>: ${b.seen} of ${b.markers} markers seen`,
        known ? `displacement ${num(b.distance_mm)} mm (${d.map((x) => num(x)).join(", ")})` :
          '<span class="unknown">displacement NOT KNOWN now</span>' + (b.distance_mm !== null ? ` (last ${num(b.distance_mm)} mm, ${num(live.age_s)} s ago)` : ""),
        !b.breathes ? "breathing: none seen (fitted rigidly)" :
          known ? `breathing ${num(b.breathing_mm)} mm, ${b.rate_per_min === null ? "rate not known yet (fewer than two breaths)" : num(b.rate_per_min) + " /min" + (b.rate_range_per_min ? ` (only known to ${num(b.rate_range_per_min[0])}-${num(b.rate_range_per_min[1])})` : "")}` :
            '<span class="unknown">breathing NOT KNOWN now</span>'];
      el.querySelector(".figs").innerHTML = lines.join("<br>");
      trace((s.traces || {})[String(b.band)] || [], el.querySelector("svg"));
    }
  }

  function showCams(s) {
    const byName = {};
    for (const c of s.cameras || []) byName[c.name] = c;
    for (const c of Object.values(cams)) {
      const st = byName[c.name], fed = (s.fed || []).includes(c.name);
      const recent = c.arrival !== null && Date.now() / 1000 - c.arrival < 2;
      c.pic.classList.toggle("stale", !(fed && recent));
      c.el.dataset.live = fed && recent ? "yes" : "no";
      c.pic.querySelector(".veil").textContent = fed ? "NO RECENT FRAME" : "NOT RECORDING";
      const counts = c.el.querySelector(".counts");
      if (!st) { counts.textContent = "no frames"; continue; }
      counts.innerHTML = `${st.frames} recorded, ${st.dropped} dropped` + (st.fps !== null ? `, ${num(st.fps)} fps` : "") +
        (st.state === "ok" || st.state === "closed" ? ` (${st.state})` : ` <span class="bad">${st.state}</span>`);
      c.el.dataset.frames = st.frames; c.el.dataset.dropped = st.dropped;
    }
  }

  function showAfter(s) {
    const after = $("after");
    after.hidden = !s.summary;
    if (!s.summary) return;
    const v = $("verdict");
    v.className = "verdict " + s.summary.status;
    v.textContent = `${s.summary.status.toUpperCase()}` + (s.summary.verdict ? `: ${s.summary.verdict}` : ": every camera recorded whole and the patient was watched");
    $("summary").textContent = s.summary.lines.join("\n");
    root.dataset.recording = s.summary.status;
    const a = s.analysis, box = $("analysis");
    $("analyse").disabled = !!(a && a.state === "running");
    box.dataset.state = a ? a.state : "none";
    if (!a) { box.innerHTML = ""; return; }
    if (a.state === "running") {
      const p = a.progress;
      box.innerHTML = `<p>analysing: ${a.stage} (${num(a.elapsed_s)} s)</p>` +
        (p ? `<progress max="${p[1]}" value="${p[0]}"></progress> ${p[0]}/${p[1]} frame pairs` : "");
      return;
    }
    if (a.state === "failed") { box.innerHTML = '<p class="error"></p>'; box.querySelector("p").textContent = `analysis failed: ${a.error}`; return; }
    const base = `/scan/files/${encodeURIComponent(s.folder)}/`;
    box.innerHTML = `<p><span class="st st-${a.result_state}">${a.result_state}</span> <span class="stored"></span></p><ul class="files"></ul><pre></pre>`;
    box.querySelector(".stored").textContent = a.stored + (a.not_written ? `; not written: ${a.not_written}` : "");
    a.files.forEach((f, i) => {       // each file by its number in the list (scan_page.py: no path in the URL)
      const li = document.createElement("li"), link = document.createElement("a");
      link.href = base + i; link.textContent = f; link.target = "_blank";
      if (f.endsWith(".html")) link.id = "report";
      li.appendChild(link); box.querySelector(".files").appendChild(li);
    });
    box.querySelector("pre").textContent = a.text + (a.notes.length ? "\n" + a.notes.join("\n") : "");
  }

  function show(s) {
    last = s;
    root.dataset.phase = s.phase; root.dataset.folder = s.folder || "";
    const ph = $("phase");
    ph.className = "phase ph-" + s.phase;
    ph.textContent = (PHASES[s.phase] || s.phase) + (s.folder ? ` ${s.folder}` : "") +
      (s.elapsed_s !== null && s.elapsed_s !== undefined && s.phase === "running" ? ` ${num(s.elapsed_s)} s` : "");
    const busy = ["starting", "running", "stopping"].includes(s.phase);
    $("start").disabled = busy; $("stop").disabled = !busy;
    if (s.error) $("message").textContent = s.error;
    if (s.folder && $("alerts").dataset.scan !== s.folder) { $("alerts").innerHTML = ""; $("alerts").dataset.scan = s.folder; }
    showStatus(s); showSix(s); showBands(s); showCams(s); showAlerts(s.alerts || []); showAfter(s);
    $("steps").innerHTML = ""; $("notes").innerHTML = "";
    for (const [n, t] of s.steps || []) { const li = document.createElement("li"); li.textContent = `${n}: ${t}`; $("steps").appendChild(li); }
    for (const t of s.notes || []) { const li = document.createElement("li"); li.textContent = t; $("notes").appendChild(li); }
  }

  const es = new EventSource("/scan/events");
  es.addEventListener("scan", (e) => { lastEvent = Date.now(); show(JSON.parse(e.data)); });
  es.addEventListener("alert", (e) => { lastEvent = Date.now(); showAlerts([JSON.parse(e.data)]); });
  es.addEventListener("frame", (e) => {
    lastEvent = Date.now();
    const d = JSON.parse(e.data), c = cams[d.camera];
    if (c) { c.want = d.seq; pump(c); }
  });
  setInterval(() => {
    const lost = Date.now() - lastEvent > 4000, c = $("contact");
    c.className = "contact " + (lastEvent === 0 ? "wait" : lost ? "lost" : "ok");
    c.textContent = lastEvent === 0 ? "connecting…" : lost ? "NO CONTACT WITH THE CONSOLE: what is shown is old" : "connected";
    if (lost && last) { $("status").className = "status st-none"; $("status").querySelector(".word").textContent = "NOT KNOWN"; root.dataset.status = ""; }
  }, 500);
})();
