// The Daily QA page: run the daily QA (progress over the page's own event stream, /qa/events), show its
// result per camera (state in colour and words, figures against their windows, the drift plot), push to
// QATrack+, set a baseline after a confirmation naming what changes. Every POST carries the page's token.
"use strict";
(function () {
  const root = document.getElementById("qa");
  const token = root.dataset.token;
  const cameras = root.dataset.cameras ? root.dataset.cameras.split(",") : [];
  const $ = (id) => document.getElementById(id);
  const STEPS = { starting: "starting", connect: "connecting to the camera", reachable: "asking for its device info",
                  params: "checking its locked parameters", clock: "measuring its clock", drift: "LED frames for the drift",
                  done: "done", "reading the baselines": "reading the baselines", stored: "storing the run" };
  const AT = { connect: 0, reachable: 0.05, params: 0.1, clock: 0.15, drift: 0.3, done: 1 };
  let skew = 0;                 // server clock minus this browser's, s
  let job = null;               // the latest snapshot
  let seenVersion = null;
  let mine = null;              // the start time of the job this page started
  let saidFor = null;           // the start time of the job whose end was said
  let baselines = {};

  const el = (tag, cls, text) => { const e = document.createElement(tag); if (cls) e.className = cls; if (text !== undefined) e.textContent = text; return e; };
  const badge = (word, cls) => el("span", "st st-" + (cls || word).replace(/ /g, ""), word);
  const hhmmss = window.vtsClock.time;

  function say(text, kind) {
    const s = $("said");
    s.textContent = text;
    s.className = "said " + (kind || "");
  }

  function post(url, body) {
    return fetch(url, { method: "POST", headers: { "Content-Type": "application/json", "X-Console-Token": token },
                        body: JSON.stringify(body || {}) })
      .then((r) => r.json().catch(() => ({ error: `HTTP ${r.status}` })).then((d) => ({ ok: r.ok, status: r.status, d })));
  }

  // "started", unless the job's end was already said (its events can come before this answer)
  function startedSay(d, text) {
    if (saidFor === d.started) return;
    if (job && job.started === d.started && job.state !== "running") { onJob(job); return; }
    say(text);
  }

  // -- progress -----------------------------------------------------------------------------------------
  function showProgress(s) {
    const box = $("progress");
    if (s.state === "idle") { box.hidden = true; return; }
    box.hidden = false;
    box.dataset.state = s.state;
    box.dataset.kind = s.kind;
    $("p-what").textContent = s.kind === "baseline" ? "Drift baseline" : "Daily QA";
    const st = $("p-state");
    const word = s.state === "running" ? "RUNNING" : s.state === "done" ? "DONE" : "FAILED";
    st.className = "st st-" + (s.state === "running" ? "running" : s.state === "done" ? "done" : "failed");
    st.textContent = word;
    const end = s.state === "running" ? s.now : (s.finished || s.now);
    $("p-elapsed").textContent = `${Math.max(0, end - s.started).toFixed(1)} s since ${hhmmss(s.started)}, by ${s.user}`;
    const n = (s.cameras || []).length || 1;
    let line;
    if (s.state === "failed") line = s.error;
    else if (s.state === "done") line = s.kind === "baseline" ? "baseline set" : `finished: run ${s.run}`;
    else if (!s.camera) line = STEPS[s.step] || s.step;
    else {
      line = `camera ${s.camera} (${s.index || "?"} of ${n}): ${STEPS[s.step] || s.step}`;
      if (s.needed) line += `, frames ${s.taken} of ${s.needed}` + (s.taken === s.needed && s.kind === "daily" ? " (analysing)" : "");
    }
    const p = $("p-line");
    p.textContent = line;
    p.className = s.state === "failed" ? "error" : "";
    p.dataset.camera = s.camera || "";
    p.dataset.step = s.step || "";
    p.dataset.taken = String(s.taken || 0);
    p.dataset.needed = String(s.needed || 0);
    let frac = s.state === "running" ? 0 : 1;
    if (s.state === "running" && s.index) {
      const within = s.step === "drift" && s.needed ? AT.drift + 0.7 * s.taken / s.needed : (AT[s.step] || 0);
      frac = (s.index - 1 + within) / n;
    }
    $("p-bar").style.width = `${(100 * Math.min(1, frac)).toFixed(1)}%`;
    const list = $("p-cams");
    list.innerHTML = "";
    for (const c of s.cameras || []) {
      const li = el("li");
      li.dataset.camera = c;
      const done = (s.done || {})[c];
      li.append(`${c}: `, done ? badge(done) : el("span", "small", c === s.camera && s.state === "running" ? "now" : "waiting"));
      list.append(li);
    }
  }

  function onJob(s) {
    const before = job;
    job = s;
    skew = s.now - Date.now() / 1000;
    showProgress(s);
    $("push").disabled = s.pushing || !root.dataset.hasRig;
    // a job ended: seen running here, or started here (one that ends before this page hears it
    // running, e.g. refused at once for want of a baseline, is said too), and said once
    const ranHere = before && before.state === "running" && before.started === s.started;
    const ended = s.state !== "running" && s.state !== "idle" && s.started !== saidFor &&
      (ranHere || (mine !== null && s.started === mine));
    if (!ended) return;
    saidFor = s.started;
    if (s.state === "failed") { say(`The ${s.what} failed: ${s.error}`, "refused"); load(); return; }
    if (s.kind === "daily") {
      if (s.result) showResult(s.result, "This daily QA");
      say(s.note ? s.note : `Daily QA done: ${s.result ? s.result.state : ""} (run ${s.run}).`, s.note ? "refused" : "ok");
    } else {
      const made = s.result && s.result.baseline ? Object.entries(s.result.baseline).map(([c, k]) => `${c} ${k} markers`).join(", ") : "";
      // said once the page has the new baseline: a dialog opened at once names it
      const line = `Baseline set (run ${s.run}): ${made}.`;
      load().then(() => say(line, "ok"));
    }
  }

  // -- the result ---------------------------------------------------------------------------------------
  function showResult(v, title) {
    const t = $("r-title");
    t.innerHTML = "";
    t.dataset.run = v.run === null ? "" : String(v.run);
    t.dataset.state = v.state;
    t.append(`${title || "Latest daily QA"}${v.run !== null ? `: run ${v.run}` : " (NOT stored)"} `, badge(v.state));
    const f = $("r-facts");
    f.innerHTML = "";
    f.append(`${v.procedure}, started ${v.started}` + (v.finished ? `, finished ${v.finished}` : "") + (v.operator ? `, by ${v.operator}` : "") + ". ");
    if (v.run !== null) {
      const a = el("a", "", `Run ${v.run} on the History page`);
      a.href = `/history/run/${v.run}`;
      a.id = "history-link";
      f.append(a);
    }
    showPush(v);
    const box = $("r-cams");
    box.innerHTML = "";
    for (const c of v.cameras) box.append(cameraCard(c, v.run));
  }

  function showPush(v) {
    const p = $("r-push");
    p.innerHTML = "";
    if (!v.stored) return;
    const ps = v.push;
    p.dataset.state = ps ? ps.state : "not pushed";
    p.append("QATrack+: ", ps ? badge(ps.state) : badge("not pushed", "notpushed"));
    if (ps && ps.state === "sent") p.append(` ${ps.remote}`);
    else if (ps && ps.message) p.append(` ${ps.message}`);
  }

  function cameraCard(c, run) {
    const card = el("section", "qa-cam");
    card.dataset.camera = c.camera;
    card.dataset.state = c.state;
    card.dataset.measured = c.measured ? "yes" : "no";
    const h = el("h3");
    h.append(c.camera, c.measured ? badge(c.state) : badge("NOT MEASURED", "NOTMEASURED"));
    if (!c.measured) h.append(el("span", "small", `(stored as ${c.state})`));
    card.append(h);
    if (!c.measured) card.append(el("p", "why", c.why));
    const body = el("div", "body");
    const table = el("table");
    table.innerHTML = "<thead><tr><th>Figure</th><th>Value</th><th>State</th><th>Window</th></tr></thead>";
    const tb = el("tbody");
    for (const g of c.figures) {
      const tr = el("tr");
      tr.dataset.metric = g.metric;
      tr.append(el("td", "", g.metric), el("td", "num", `${g.value} ${g.value === "not measured" ? "" : g.unit}`.trim()));
      const td = el("td"); td.append(badge(g.state)); tr.append(td);
      tr.append(el("td", "win", g.window || "judged by its procedure"));
      tb.append(tr);
    }
    if (!c.figures.length) { const tr = el("tr"); tr.append(el("td", "", "no figure: not measured")); tb.append(tr); }
    table.append(tb);
    body.append(table);
    const fig = el("figure");
    const img = el("img", "drift");
    img.alt = `drift of ${c.camera} inside its tolerance and action windows`;
    img.onerror = () => { img.remove(); fig.append(el("p", "noplot", `no drift plot: ${c.camera} has no drift measured in the store in the last 60 days`)); };
    img.src = c.plot;
    fig.append(img);
    body.append(fig);
    card.append(body);
    if (c.problems.length && c.measured) {
      const ul = el("ul", "problems");
      for (const p of c.problems) ul.append(el("li", "", p));
      card.append(ul);
    }
    return card;
  }

  function load() {
    return fetch("/qa/state", { cache: "no-store" }).then((r) => r.json()).then((d) => {
      baselines = d.baselines || {};
      if (d.store_error) { $("r-facts").textContent = d.store_error; $("r-facts").className = "error"; return; }
      if (d.latest) showResult(d.latest);
      else {
        $("r-title").textContent = "No daily QA of this room in the store yet";
        $("r-facts").textContent = Object.values(baselines).some((b) => b) ? "Run the daily QA." :
          "Set a baseline first (a physicist), then run the daily QA.";
      }
      if (!job) onJob(d.job);
    }).catch(() => say("the console did not answer", "refused"));
  }

  // -- the buttons --------------------------------------------------------------------------------------
  const frames = () => Number($("frames").value);

  $("run").addEventListener("click", () => {
    post("/qa/run", { frames: frames() }).then(({ ok, d }) => {
      if (ok) { mine = d.started; startedSay(d, `Daily QA started (${cameras.join(", ")}, ${d.frames} frames each).`); }
      else say(d.error, "refused");
    });
  });

  $("push").addEventListener("click", () => {
    $("push").disabled = true;
    say("Pushing to QATrack+…");
    post("/qa/push").then(({ ok, d }) => {
      $("push").disabled = false;
      if (!ok) { say(d.error, "refused"); return; }
      const box = $("pushed");
      box.hidden = false;
      $("push-summary").textContent = d.summary;
      const ul = $("push-rows");
      ul.innerHTML = "";
      for (const o of d.outcomes) {
        const li = el("li");
        li.dataset.run = String(o.run_id);
        li.dataset.state = o.state;
        li.append(badge(o.state), ` ${o.line}`);
        ul.append(li);
      }
      say(d.summary, d.counts.refused || d.counts.pending ? "refused" : "ok");
      load();
    });
  });

  const dialog = $("confirm-baseline");
  $("baseline").addEventListener("click", () => {
    $("confirm-text").textContent = `The drift baseline of ${cameras.join(", ")} becomes the wall markers seen now ` +
      `(LED on, ${frames()} frames each). Every daily QA from now on is compared with it: a camera that has moved ` +
      `since is then taken as where it should be.`;
    const ul = $("confirm-cams");
    ul.innerHTML = "";
    for (const c of cameras) {
      const b = baselines[c];
      ul.append(el("li", "", b ? `${c}: replaces the baseline of ${b.taken} (run ${b.run}, ${b.markers} markers)` :
                                  `${c}: its first baseline`));
    }
    dialog.returnValue = "";
    dialog.showModal();
  });
  dialog.addEventListener("close", () => {
    if (dialog.returnValue !== "yes") { say("Baseline not changed."); return; }
    post("/qa/baseline", { confirm: true, frames: frames() }).then(({ ok, d }) => {
      if (ok) { mine = d.started; startedSay(d, `Setting the baseline of ${cameras.join(", ")}…`); }
      else say(d.error, "refused");
    });
  });

  // -- the events ---------------------------------------------------------------------------------------
  const es = new EventSource("/qa/events");
  es.addEventListener("qa", (e) => {
    const s = JSON.parse(e.data);
    if (s.version === seenVersion && job && job.state === s.state) { job.now = s.now; showProgress(job); return; }
    seenVersion = s.version;
    onJob(s);
  });
  setInterval(() => { if (job && job.state === "running") { job.now = Date.now() / 1000 + skew; showProgress(job); } }, 250);
  root.dataset.hasRig = $("run").disabled ? "" : "yes";
  load();
})();
