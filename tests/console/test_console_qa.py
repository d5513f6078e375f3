"""The console's Daily QA page (issue 23 §1, §5) in Debian's Chromium (Playwright), against the
simulated rig over HTTP (two Axis cameras and the QATrack+ stand-in), a real SQLite store.

The console is served in this process as `vts console` serves it (tests/console_live.py:
serve.py's parts), so that the tests can read what it logged and what its hub did. The page: a
daily QA before any baseline fails in one sentence; the baseline needs the page's confirmation
(a POST without it is refused) and is then stored; the daily QA runs from the page with its
progress live (camera, step, frames taken of needed, elapsed), a second click is said to be
refused and nothing starts twice, the result shows each camera's state, figures against their
windows and drift plot, and is the run in the store; with the Room page streaming each camera
and the cameras taking one viewer (max_viewers=1) the hub steps aside while the QA takes its
frames (no frame taken while the hub's stream is open) and shows them (RECORDING); a camera off
the network shows NOT MEASURED, never OK; the push shows refused with QATrack+'s sentence, then
sent.
"""

from __future__ import annotations

import os
import re
import threading
import time

import pytest
import requests

from console_live import qa_rig_yaml, served_room, start_console, stop_console, until, wait_js
from vts_hw.config import load_rig
from vts_hw.drivers.registry import open_cameras
from vts_hw.sim_devices.rig import SimRig
from vts_hw.store import ResultsStore

# a hang detector, not a speed goal: the simulated cameras render the QA's frames as it asks for
# them, and in a whole-suite run on a loaded machine (the other worker's tests start CPU loads of
# their own) a QA did not end within 60 s and the module's next tests found it still running
QA_S = 600
pytestmark = pytest.mark.timeout(3 * QA_S)
FRAMES = 3


@pytest.fixture(scope="module")
def qa_room(tmp_path_factory):
    folder = tmp_path_factory.mktemp("console-qa")
    with SimRig(n_cameras=2, seed=5, qatrack=True) as rig, rig.env():
        rig_yaml = qa_rig_yaml(rig, folder)
        db = folder / "results.sqlite"
        ResultsStore(db).close()  # the console updates a store; `vts qa` made this one
        cfg = load_rig(str(rig_yaml))
        cams = {c.name: c for c in open_cameras(cfg.cameras)}
        with served_room(rig, cams, db, marker_hz=1.0, idle_close_s=1.0, rig_config=cfg) as served:
            yield rig, served, db


@pytest.fixture()
def qa_page(browser, qa_room):
    _, served, _ = qa_room
    served.console.qa_jobs.wait(QA_S)  # a test starts with no QA running (one that timed out is not left to the next)
    pg = browser.new_page(viewport={"width": 1366, "height": 768})
    pg.goto(served.url + "qa")
    wait_js(pg, "document.getElementById('r-facts').textContent !== 'reading the results store…'")
    # every progress line and every sentence the page shows, as it shows them
    pg.evaluate("""() => { for (const [id, name] of [['p-line', 'seen'], ['said', 'saids']]) {
        window[name] = []; const e = document.getElementById(id);
        new MutationObserver(() => window[name].push(e.textContent)).observe(e, {childList: true,
                                                                                characterData: true, subtree: true}); } }""")
    yield pg
    pg.close()


@pytest.fixture()
def baselined(qa_room):
    """The module is one morning told in file order (make test keeps a module's order and worker):
    the baseline set by the first test is what the later ones measure against. Run alone, a later
    test says so at once rather than waiting QA_S for a QA that failed for want of a baseline."""
    assert runs(qa_room[2], "drift-baseline"), (
        "no drift baseline in this module's store: run test_baseline_needs_the_confirm... first (the whole module)"
    )


def said(page, contains, timeout=QA_S * 1000):
    """The first sentence the page said (since it opened) that holds ``contains``."""
    wait_js(page, "t => window.saids.some(s => s.includes(t))", contains, timeout)
    return page.evaluate("t => window.saids.find(s => s.includes(t))", contains)


def runs(db, procedure):
    with ResultsStore(db, mode="read") as store:
        return [r for r in store.runs() if r.procedure == procedure]


def actions(served, what):
    return [a for a in served.console.actions.recent(100) if a.what == what]


def test_baseline_needs_the_confirm_and_a_qa_before_it_fails_in_one_sentence(qa_room, qa_page):
    rig, served, db = qa_room
    page = qa_page
    page.fill("#frames", str(FRAMES))
    page.click("#run")
    text = said(page, "failed")
    assert "camera cam1 has no drift baseline" in text and "--set-baseline" in text, text
    assert runs(db, "daily") == [] and "Set a baseline first" in page.inner_text("#r-facts")
    # a POST without the page's confirmation changes nothing
    r = requests.post(
        served.url + "qa/baseline", json={"frames": 2}, headers={"X-Console-Token": served.console.token}, timeout=10
    )
    assert r.status_code == 400 and "only when confirmed" in r.json()["error"]
    page.click("#baseline")
    assert page.is_visible("#confirm-baseline")
    ask = page.inner_text("#confirm-baseline")
    assert "cam1, cam2" in ask and "cam1: its first baseline" in ask and "compared with it" in ask
    page.click("#confirm-no")
    said(page, "Baseline not changed")
    time.sleep(0.5)
    assert runs(db, "drift-baseline") == []
    page.click("#baseline")
    page.click("#confirm-yes")
    text = said(page, "Baseline set")
    assert "cam1 5 markers" in text and "cam2 5 markers" in text, text
    (run,) = runs(db, "drift-baseline")
    assert run.status == "OK" and run.operator == "local" and run.rig == "sim"
    (act,) = actions(served, "drift baseline set")
    assert act.user == "local" and act.detail["run"] == run.id and act.detail["cameras"] == ["cam1", "cam2"]
    # the dialog names the baseline it would now replace
    page.click("#baseline")
    assert "replaces the baseline of" in page.inner_text("#confirm-baseline")
    assert f"(run {run.id}, 5 markers)" in page.inner_text("#confirm-baseline")
    page.click("#confirm-no")


class Sampler:
    """What each camera serves and what the hub does, sampled every few ms while the QA runs."""

    def __init__(self, rig, hub):
        self.rig, self.hub, self.rows, self.stop = rig, hub, [], threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while not self.stop.is_set():
            row = {
                n: (s.counter("snapshots_served"), s.counter("active_streams"), self.hub.status(n)["doing"])
                for n, s in self.rig.servers.items()
            }
            self.rows.append(row)
            time.sleep(0.003)

    def close(self):
        self.stop.set()
        self.thread.join(5)


def test_the_daily_qa_runs_from_the_page_and_the_hub_steps_aside(qa_room, baselined, qa_page, browser):
    rig, served, db = qa_room
    for srv in rig.servers.values():
        srv.set_faults(max_viewers=1)  # a second viewer would be refused (503)
    room = browser.new_page(viewport={"width": 1366, "height": 768})
    room.goto(served.url)  # the Room page streams both cameras
    try:
        for name in ("cam1", "cam2"):
            assert until(
                lambda name=name: (
                    room.eval_on_selector(f'section[data-camera="{name}"]', "e => e.dataset.live") == "yes"
                ),
                30,
            ), name
            assert rig.servers[name].counter("active_streams") == 1
        page = qa_page
        page.fill("#frames", str(FRAMES))
        sampler = Sampler(rig, served.hub)
        try:
            page.click("#run")
            page.click("#run")  # a second click while it runs
            assert "a daily QA is already running (started by local" in said(page, "already running")
            said(page, "Daily QA done")
        finally:
            sampler.close()
        # the progress, as it went: which camera, which step, frames taken of needed
        seen = page.evaluate("window.seen")
        # (the page shows the latest state at each event: a short step may pass unseen; the drift
        # step's first state lasts while the hub steps aside)
        assert any(
            re.fullmatch(rf"camera cam1 \(1 of 2\): LED frames for the drift, frames \d of {FRAMES + 1}.*", s)
            for s in seen
        ), seen
        assert any(s.startswith("camera cam2 (2 of 2): ") for s in seen), seen
        assert re.match(r"\d+\.\d s since \d\d:\d\d:\d\d UTC, by local", page.inner_text("#p-elapsed"))
        # the result: each camera's state in colour and words, its figures in their windows, its plot
        run_id = int(page.get_attribute("#r-title", "data-run"))
        (daily,) = runs(db, "daily")  # started once
        assert daily.id == run_id and daily.status == "OK" and daily.operator == "local"
        for name in ("cam1", "cam2"):
            card = f'section.qa-cam[data-camera="{name}"]'
            assert page.get_attribute(card, "data-state") == "OK" and page.get_attribute(card, "data-measured") == "yes"
            assert page.inner_text(f"{card} h3 .st") == "OK"
            assert (
                page.eval_on_selector(f"{card} h3 .st", "e => getComputedStyle(e).backgroundColor")
                == "rgb(220, 252, 231)"
            )
            row = page.inner_text(f'{card} tr[data-metric="drift_x_px"]')
            assert "px" in row and "OK within ±1" in row and "ACTION beyond ±2 px" in row, row
            wait_js(
                page,
                "c => { const i = document.querySelector(c + ' img.drift');"
                " return i && i.complete && i.naturalWidth > 0; }",
                card,
                120_000,
            )
        assert page.get_attribute("#history-link", "href") == f"/history/run/{run_id}"
        with ResultsStore(db, mode="read") as store:
            stored = {(m.subject, m.metric) for m in store.measurements(run_id=run_id)}
        assert {("cam1", "drift_x_px"), ("cam2", "drift_y_px"), ("cam2", "clock_offset_s")} <= stored
        (act,) = [a for a in actions(served, "daily QA run") if a.detail.get("run") == run_id]
        assert act.user == "local" and act.detail["state"] == "OK"
        # the hub stepped aside: no snapshot was served while the hub's stream of that camera was open,
        # and the QA's frames reached the Room page (RECORDING); then the hub streamed again
        for name in ("cam1", "cam2"):
            pairs = [(a[name], b[name]) for a, b in zip(sampler.rows, sampler.rows[1:]) if b[name][0] > a[name][0]]
            assert pairs, name
            assert all(a[1] == 0 or b[1] == 0 for a, b in pairs), [p for p in pairs if p[0][1] and p[1][1]]
            assert any(r[name][2] == "recording" for r in sampler.rows), name
            assert until(
                lambda name=name: (
                    rig.servers[name].counter("active_streams") == 1 and served.hub.status(name)["doing"] == "streaming"
                ),
                20,
            ), name
    finally:
        room.close()
        for srv in rig.servers.values():
            srv.set_faults(max_viewers=None)


def test_a_camera_that_does_not_answer_is_not_measured_never_ok(qa_room, baselined, qa_page):
    rig, served, db = qa_room
    rig.servers["cam2"].faults.offline = True
    try:
        page = qa_page
        page.fill("#frames", "2")
        page.click("#run")
        said(page, "Daily QA done")
    finally:
        rig.servers["cam2"].faults.offline = False
    card = 'section.qa-cam[data-camera="cam2"]'
    assert page.get_attribute(card, "data-measured") == "no" and page.get_attribute(card, "data-state") == "ACTION"
    assert page.inner_text(f"{card} h3 .st") == "NOT MEASURED"
    assert "the camera did not answer" in page.inner_text(f"{card} .why")
    assert page.get_attribute('section.qa-cam[data-camera="cam1"]', "data-state") == "OK"
    assert page.get_attribute("#r-title", "data-state") == "ACTION"
    run_id = int(page.get_attribute("#r-title", "data-run"))
    with ResultsStore(db, mode="read") as store:
        assert store.run(run_id).status == "ACTION"
        reach = {m.subject: m.value for m in store.measurements(run_id=run_id) if m.metric == "camera_reachable"}
    assert reach == {"cam1": 1.0, "cam2": 0.0}


def test_the_push_shows_refused_with_qatracks_sentence_then_sent(qa_room, baselined, qa_page):
    rig, served, db = qa_room
    site = rig.qatrack_site
    daily = [r.id for r in runs(db, "daily")]
    assert daily
    page = qa_page
    site.fault = ("400", "cam1_dx: value out of the list's range")
    try:
        page.click("#push")
        said(page, "QATrack+: ")
        rows = page.query_selector_all("#push-rows li")
        assert rows and rows[0].get_attribute("data-state") == "refused"
        assert "value out of the list's range" in rows[0].inner_text() and rows[0].inner_text().startswith("refused")
        assert all(r.get_attribute("data-state") != "sent" for r in rows)
    finally:
        site.fault = None
    page.click("#push")
    said(page, f"QATrack+: {len(daily)} of {len(daily)} sent")
    assert {r.get_attribute("data-state") for r in page.query_selector_all("#push-rows li")} == {"sent"}
    wait_js(page, "document.getElementById('r-push').dataset.state === 'sent'")
    with ResultsStore(db, mode="read") as store:
        assert {i.run_id: i.state for i in store.outbox_items("qatrack")} == {r: "sent" for r in daily}
    assert site.posts == len(daily)
    pushes = actions(served, "push to QATrack+")
    assert len(pushes) == 2 and pushes[0].detail["sent"] == len(daily) and pushes[1].detail["refused"] >= 1


def test_vts_console_serves_the_page_with_the_rigs_qa(tmp_path):
    """As users run it: the page can run the rig's QA; a POST without the page's token, or with
    frames out of range, is refused before anything starts."""
    with SimRig(n_cameras=1, seed=2) as rig, rig.env():
        rig_yaml, _ = rig.write(tmp_path)
        env = {**os.environ, **rig.env_vars(), "VTS_CONFIG": str(rig_yaml), "VTS_STORE": str(tmp_path / "r.sqlite")}
        p, url = start_console(["--port", "0"], env)
        try:
            page = requests.get(url + "qa", timeout=10).text
            assert '<button type="button" id="run" >' in page and "without a rig config" not in page
            token = re.search(r'data-token="([^"]+)"', page).group(1)
            r = requests.post(url + "qa/run", json={}, timeout=10)
            assert r.status_code == 403
            r = requests.post(url + "qa/run", json={"frames": 0}, headers={"X-Console-Token": token}, timeout=10)
            assert r.status_code == 400 and "frames must be a whole number from 1 to 50" in r.json()["error"]
        finally:
            code, out, err = stop_console(p)
        assert code == 0 and "Traceback" not in err, err
