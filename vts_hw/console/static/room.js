// The Room page: live pictures (one fetch in flight per camera), markers drawn over them, the room's state.
// A picture is shown as live only while its camera delivers and the picture is recent; otherwise it is
// greyed with its age, and a camera that does not answer says NOT ANSWERING. Each marker is labelled as what
// it is where that is known (wall marker, phantom sphere, band marker), else "unidentified" and numbered,
// with a legend; the LED state is the one read back from the camera.
"use strict";
(function () {
  const token = document.querySelector('meta[name="console-token"]').content;
  const WORDS = { streaming: "LIVE", recording: "RECORDING", idle: "IDLE", off: "OFF",
                  "not answering": "NOT ANSWERING" };
  const KIND_WORDS = { wall: ["wall marker", "wall markers"], phantom: ["phantom sphere", "phantom spheres"],
                       band: ["band marker", "band markers"], unidentified: ["unidentified", "unidentified"] };
  const KIND_ORDER = ["band", "phantom", "wall", "unidentified"];
  const cams = {};
  let skew = 0;               // server clock minus this browser's, s (from each room event)
  let lastEvent = 0;          // Date.now() of the last event from the console

  document.querySelectorAll("section.camera").forEach((el) => {
    const name = el.dataset.camera;
    cams[name] = { name, el, img: el.querySelector("img.picture"), svg: el.querySelector("svg.overlay"),
                   frame: el.querySelector(".frame"), want: null, shown: null, arrival: null, busy: false,
                   url: null, status: null, found: null, };
    el.querySelector(".led-on").addEventListener("click", () => led(name, true));
    el.querySelector(".led-off").addEventListener("click", () => led(name, false));
  });

  const serverNow = () => Date.now() / 1000 + skew;
  const fmtAge = (s) => s < 90 ? `${s.toFixed(0)} s` : s < 5400 ? `${(s / 60).toFixed(0)} min` : `${(s / 3600).toFixed(1)} h`;
  const hhmmss = window.vtsClock.time;

  // -- pictures: ask for the latest when told of a new one and the last one is shown --------------------
  function pump(c) {
    if (c.busy || c.want === null || c.want === c.shown) return;
    c.busy = true;
    fetch(`/frame/${encodeURIComponent(c.name)}`, { cache: "no-store" })
      .then((r) => {
        if (!r.ok) throw new Error(`HTTP ${r.status}`);
        const seq = Number(r.headers.get("X-Frame-Seq"));
        const arrival = Number(r.headers.get("X-Frame-Arrival"));
        return r.blob().then((b) => ({ b, seq, arrival }));
      })
      .then(({ b, seq, arrival }) => new Promise((resolve, reject) => {
        const url = URL.createObjectURL(b);
        c.img.onload = () => {
          if (c.url) URL.revokeObjectURL(c.url);
          c.url = url; c.shown = seq; c.arrival = arrival;
          c.img.dataset.seq = String(seq);
          drawMarkers(c); judge(c); resolve();
        };
        c.img.onerror = () => { URL.revokeObjectURL(url); reject(new Error("not a picture")); };
        c.img.src = url;
      }))
      .then(() => { c.busy = false; pump(c); })
      .catch(() => { c.busy = false; setTimeout(() => pump(c), 500); });
  }

  // -- markers over the picture, in the frame's own pixels --------------------------------------------------
  function drawMarkers(c) {
    const f = c.found;
    const svg = c.svg;
    while (svg.firstChild) svg.removeChild(svg.firstChild);
    const marks = c.el.querySelector(".marks");
    if (!f) return;
    if (f.problem) { marks.textContent = f.problem; marks.className = "marks error"; return; }
    svg.setAttribute("viewBox", `0 0 ${f.width} ${f.height}`);
    svg.dataset.seq = String(f.seq);
    const ns = "http://www.w3.org/2000/svg";
    const size = Math.max(12, f.height / 28);
    const counts = {};
    for (const m of f.markers) {
      const kind = m.kind || "unidentified";
      counts[kind] = (counts[kind] || 0) + 1;
      const circle = document.createElementNS(ns, "circle");
      circle.setAttribute("cx", m.x); circle.setAttribute("cy", m.y);
      circle.setAttribute("r", Math.max(m.d / 2 + 4, 6));
      circle.setAttribute("class", "k-" + kind);
      circle.dataset.x = m.x; circle.dataset.y = m.y; circle.dataset.n = m.n; circle.dataset.kind = kind;
      svg.appendChild(circle);
      const label = document.createElementNS(ns, "text");
      label.setAttribute("x", m.x + m.d / 2 + 6); label.setAttribute("y", m.y - m.d / 2 - 4);
      label.setAttribute("font-size", size);
      label.setAttribute("class", "k-" + kind);
      label.textContent = kind === "unidentified" ? `? ${m.n}` : (m.name || String(m.n));
      svg.appendChild(label);
    }
    marks.className = "marks";
    const parts = KIND_ORDER.filter((k) => counts[k]).map((k) => `${counts[k]} ${KIND_WORDS[k][counts[k] === 1 ? 0 : 1]}`);
    marks.textContent = `${f.markers.length} found${parts.length ? ": " + parts.join(", ") : ""} (picture ${f.seq})`;
    legend(c, f, counts);
  }

  // -- the legend: what each colour is, and what named the markers ------------------------------------------
  function legend(c, f, counts) {
    const ul = c.el.querySelector(".legend");
    ul.innerHTML = "";
    const known = {};
    for (const l of f.legend || []) known[l.kind] = l;
    for (const kind of KIND_ORDER) {
      const l = known[kind];
      if (!l && !counts[kind]) continue;
      const li = document.createElement("li");
      li.dataset.kind = kind;
      const sw = document.createElement("span");
      sw.className = "swatch k-" + kind;
      const what = kind === "unidentified" ? "unidentified (numbered): not a known wall marker, sphere or band marker" :
        `${KIND_WORDS[kind][1]}: ${l.found} of ${l.known} named here, from ${l.source}`;
      li.append(sw, " " + what);
      ul.appendChild(li);
    }
    if (!ul.firstChild) {
      const li = document.createElement("li");
      li.className = "small";
      li.textContent = "no names known for this camera (no drift baseline, no scan, no phantom located)";
      ul.appendChild(li);
    }
  }

  // -- live or not: the words and the veil -----------------------------------------------------------------
  function judge(c) {
    const st = c.status;
    const lost = Date.now() - lastEvent > 4000;
    const age = c.arrival === null ? null : Math.max(0, serverNow() - c.arrival);
    const doing = st ? st.doing : null;
    const live = !lost && st && (doing === "streaming" || doing === "recording") && age !== null && age <= st.fresh_within;
    c.frame.classList.toggle("stale", !live);
    c.frame.classList.toggle("dead", !lost && doing === "not answering");
    c.el.dataset.live = live ? "yes" : "no";
    const word = c.el.querySelector(".veil-word");
    const ageText = c.el.querySelector(".veil-age");
    if (lost) word.textContent = "NO CONTACT WITH THE CONSOLE";
    else if (doing === "not answering") word.textContent = "NOT ANSWERING";
    else if (age === null) word.textContent = doing === "idle" ? "IDLE" : "NO PICTURE YET";
    else word.textContent = "PICTURE NOT LIVE";
    ageText.textContent = age === null ? "" : `last picture ${fmtAge(age)} old (${hhmmss(c.arrival)})`;
  }

  function showState(c, s) {
    c.status = s;
    const doing = c.el.querySelector(".doing");
    doing.className = "doing state-" + s.doing.replace(/ /g, "");
    doing.querySelector(".word").textContent = WORDS[s.doing] || s.doing.toUpperCase();
    doing.querySelector(".why").textContent = s.doing === "not answering" ? (s.why || "no frame from it") :
      s.doing === "idle" ? "nobody watching: no stream" : s.doing === "recording" ? "frames of the recording" :
      s.doing === "streaming" ? "the console's own stream" : "";
    c.el.dataset.doing = s.doing;
    const led = c.el.querySelector(".led");
    led.className = "led " + s.led;
    led.textContent = s.led === "unknown" ? `not known: ${s.led_why || "not read yet"}` :
      `${s.led.toUpperCase()} (read from the camera ${hhmmss(s.led_at)})`;
    c.el.dataset.led = s.led;
    const ledErr = c.el.querySelector(".led-error");
    ledErr.textContent = s.led_error ? `${s.led_error} (${hhmmss(s.led_asked_at)})` : "";
    c.el.dataset.ledTook = s.led_asked ? (s.led_error ? "no" : "yes") : "";
    const off = c.el.querySelector(".offset");
    if (s.offset_error) { off.className = "offset error"; off.textContent = `not measured: ${s.offset_error}`; }
    else if (s.offset_s === null) { off.className = "offset"; off.textContent = "not measured yet"; }
    else {
      off.className = "offset";
      off.textContent = `${s.offset_s >= 0 ? "+" : ""}${(s.offset_s * 1000).toFixed(1)} ms ± ${(s.offset_unc_s * 1000).toFixed(1)} ms ` +
        `(camera − host, measured ${fmtAge(serverNow() - s.offset_at)} ago)`;
    }
    const qa = c.el.querySelector(".qa");
    qa.innerHTML = "";
    const badge = document.createElement("span");
    if (s.qa_state) {
      badge.className = "qa-" + s.qa_state; badge.textContent = s.qa_state;
      qa.append(badge, ` run ${s.qa_run}, ${window.vtsClock.stamp(s.qa_at)}`);
    } else {
      badge.className = "qa-none"; badge.textContent = s.qa_note || "no daily QA"; qa.append(badge);
    }
    c.el.dataset.qa = s.qa_state || "none";
  }

  function led(name, on) {
    fetch(`/camera/${encodeURIComponent(name)}/led`, {
      method: "POST", headers: { "Content-Type": "application/json", "X-Console-Token": token },
      body: JSON.stringify({ on }) })
      .then((r) => r.json().catch(() => ({ error: `the console answered ${r.status}` })))
      .then((s) => {
        const c = cams[name];
        if (s.led === undefined) {        // refused (no session, a role too low, another site): say so
          c.el.querySelector(".led-error").textContent = s.error || "the switch was refused";
          c.el.dataset.ledTook = "no";
          return;
        }
        showState(c, { ...c.status, ...s });
      })
      .catch(() => { cams[name].el.querySelector(".led-error").textContent = "the console did not answer"; });
  }

  // -- the events -------------------------------------------------------------------------------------------
  const es = new EventSource(`/events?cameras=${Object.keys(cams).map(encodeURIComponent).join(",")}`);
  const contact = document.getElementById("contact");
  const heard = () => { lastEvent = Date.now(); };
  es.addEventListener("room", (e) => {
    heard();
    const room = JSON.parse(e.data);
    skew = room.now - Date.now() / 1000;
    for (const s of room.cameras) if (cams[s.camera]) { showState(cams[s.camera], s); judge(cams[s.camera]); }
    const ph = document.getElementById("phantom");      // the phantom: named, or why not (none: not looked for)
    ph.hidden = !room.phantom;
    ph.textContent = room.phantom ? room.phantom.charAt(0).toUpperCase() + room.phantom.slice(1) : "";
  });
  es.addEventListener("frame", (e) => {
    heard();
    const d = JSON.parse(e.data);
    const c = cams[d.camera];
    if (c) { c.want = d.seq; pump(c); }
  });
  es.addEventListener("markers", (e) => {
    heard();
    const d = JSON.parse(e.data);
    const c = cams[d.camera];
    if (c) { c.found = d; drawMarkers(c); }
  });

  setInterval(() => {
    const lost = Date.now() - lastEvent > 4000;
    contact.className = "contact " + (lastEvent === 0 ? "wait" : lost ? "lost" : "ok");
    contact.textContent = lastEvent === 0 ? "connecting…" : lost ?
      `NO CONTACT since ${window.vtsClock.time(lastEvent / 1000)}` : "connected";
    document.getElementById("clock").textContent = window.vtsClock.time(Date.now() / 1000);
    Object.values(cams).forEach(judge);
  }, 250);
})();
