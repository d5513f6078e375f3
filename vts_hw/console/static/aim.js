// The Room page's aim & focus (issue 24 §2): per camera a switch; while on, the console checks the camera every few
// seconds (from the frames it already receives, the LED switched and put back) and this shows each item's verdict
// in colour and words (GOOD / ADJUST and what to do / NOT KNOWN and why) beside the check's picture (the markers
// with their edge widths, the SPECT FOV, the table and the gantry's opening), in place of the live picture.
// A check that could not be made says why in one sentence; the last verdicts are then greyed with their time.
"use strict";
(function () {
  const token = document.querySelector('meta[name="console-token"]').content;
  const WORD = { good: "GOOD", adjust: "ADJUST", unknown: "NOT KNOWN" };
  const hhmmss = window.vtsClock.time;
  const cams = {};
  document.querySelectorAll("section.camera").forEach((el) => {
    const name = el.dataset.camera;
    cams[name] = { name, el, view: el.querySelector(".view"), img: el.querySelector("img.aim-picture"),
                   side: el.querySelector(".aim-side"), shownCheck: null, loading: false };
    el.dataset.aim = "off";
    el.querySelector(".aim-on").addEventListener("click", () => post(name, true));
    el.querySelector(".aim-off").addEventListener("click", () => post(name, false));
  });

  function picture(c, n) {
    if (c.loading || n === c.shownCheck) return;
    c.loading = true;
    fetch(`/aim/${encodeURIComponent(c.name)}/overlay.png`, { cache: "no-store" })
      .then((r) => { if (!r.ok) throw new Error(`HTTP ${r.status}`); return Promise.all([r.blob(), r.headers.get("X-Aim-Check")]); })
      .then(([b, got]) => new Promise((resolve) => {
        const url = URL.createObjectURL(b);
        c.img.onload = () => { if (c.url) URL.revokeObjectURL(c.url); c.url = url; c.shownCheck = Number(got);
                               c.img.dataset.check = got; resolve(); };
        c.img.onerror = () => { URL.revokeObjectURL(url); resolve(); };
        c.img.src = url;
      }))
      .catch(() => {})
      .finally(() => { c.loading = false; if (c.want !== c.shownCheck) setTimeout(() => picture(c, c.want), 300); });
  }

  function show(c, s) {
    const el = c.el;
    c.view.classList.toggle("aiming", s.on);
    const v = s.verdicts;
    const state = !s.on ? "off" : s.problem ? "not-checked" : v ? v.state : "waiting";
    el.dataset.aim = state;
    el.dataset.aimCheck = String(s.n);
    const word = el.querySelector(".aim-word");
    word.className = "aim-word " + (s.problem ? "" : (v && s.on ? v.state : ""));
    word.textContent = !s.on ? "OFF" : s.problem ? "NOT CHECKED" : v ? `${WORD[v.state]} (check ${s.n})` :
      "ON: first check under way";
    if (!s.on) { el.querySelector(".aim-error").textContent = ""; return; }
    const head = c.side.querySelector(".aim-head");
    head.innerHTML = "";
    if (v) {
      const badge = document.createElement("span");
      badge.className = "badge v-" + v.state; badge.textContent = WORD[v.state];
      const unknown = v.unknown.length ? `; not known: ${v.unknown.join(", ")}` : "";
      head.append(badge, ` check ${s.n} at ${hhmmss(s.at)}; LED found ${s.led_found}, left ${s.led_found}${unknown}`);
    } else {
      head.textContent = s.problem ? "" : "first check under way (the LED is switched for a moment)…";
    }
    c.side.querySelector(".aim-problem").textContent = s.problem ? (v ? `${s.problem} (the verdicts below are of check ${s.n}, ${hhmmss(s.at)})` : s.problem) : "";
    c.side.classList.toggle("old", !!s.problem);
    const ul = c.side.querySelector(".aim-items");
    ul.innerHTML = "";
    for (const it of (v ? v.items : [])) {
      const li = document.createElement("li");
      li.className = "v-" + it.state; li.dataset.item = it.item; li.dataset.state = it.state;
      const verdict = document.createElement("span"); verdict.className = "verdict"; verdict.textContent = WORD[it.state];
      const label = document.createElement("span"); label.className = "label"; label.textContent = it.label + ": ";
      li.title = `${it.value === null ? "not measured" : `${it.value} ${it.unit}`}; goal ${it.goal}`;
      li.append(verdict, " ", label, it.text);
      ul.appendChild(li);
    }
    if (v) { c.want = s.n; picture(c, s.n); }
  }

  function post(name, on) {
    const c = cams[name];
    const err = c.el.querySelector(".aim-error");
    fetch(`/aim/${encodeURIComponent(name)}`, {
      method: "POST", headers: { "Content-Type": "application/json", "X-Console-Token": token },
      body: JSON.stringify({ on }) })
      .then((r) => r.json().catch(() => ({ error: `the console answered ${r.status}` })))
      .then((s) => {
        err.textContent = s.error || "";
        c.el.dataset.aimRefused = s.error ? "yes" : "";
        if (s.on !== undefined && !s.error) show(c, s);
      })
      .catch(() => { err.textContent = "the console did not answer"; });
  }

  const es = new EventSource(`/aim/events?cameras=${Object.keys(cams).map(encodeURIComponent).join(",")}`);
  es.addEventListener("aim", (e) => {
    const s = JSON.parse(e.data);
    if (cams[s.camera]) show(cams[s.camera], s);
  });
})();
