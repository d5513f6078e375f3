"""The console's Scan page (issue 23 §1, §5) in a real headless Chromium, against the simulated rig.

`vts console --scans-dir DIR` runs as users run it (a subprocess) against two simulated Axis
cameras over HTTP with a breathing patient on the table; the frames are made ahead of time
(``SimRig.prerender``: the patient's plan starts playing with the scan's first stream), so the
recording is whole however busy the machine is. A scan started from the page records (files in
the folder, the recording complete, nothing dropped), shows the patient's breathing (a trace
with the patient's rate), raises the banner and the sound when the patient moves, and the
acknowledgement records who and when; "Analyse motion" writes the report into the scan folder,
served only from inside it. A camera switched off is NOT TRACKING with its reason, no figure
shown as known meanwhile, a NOT TRACKING alert, and the scan partial with the gap said.
"""

from __future__ import annotations

import json
import os
import re
import time

import numpy as np
import pytest
import requests

from console_live import chromium, start_console, stop_console, until
from vts_hw.recording.folder import read_index
from vts_hw.sim_devices.patient import BodyMove, add_patient
from vts_hw.sim_devices.rig import SimRig

# frames are made ahead (minutes on a loaded machine at worst): the timeout is a hang detector
pytestmark = pytest.mark.timeout(600)
REFERENCE_S = 4.0
DURATION_S = 20.0
MOVE_AT_S = 13.0  # after the first frame: the reference is learned and breathing traced by then


@pytest.fixture(scope="module")
def desk(tmp_path_factory):
    folder = tmp_path_factory.mktemp("console_scan")
    scans = folder / "scans"
    with SimRig(n_cameras=2, seed=3) as rig, rig.env():
        rig.ntp_sync()
        rig_yaml, _ = rig.write(folder / "rig")
        patient = add_patient(rig.scene, time.time(), 600.0, seed=5, moves=[])
        env = {
            **os.environ,
            **rig.env_vars(),
            "VTS_CONFIG": str(rig_yaml),
            "VTS_STORE": f"sqlite:///{folder / 'results.sqlite'}",
        }
        p, url = start_console(["--port", "0", "--scans-dir", str(scans)], env)
        try:
            yield rig, patient, url, scans
        finally:
            code, out, err = stop_console(p)
            for srv in rig.servers.values():
                srv.faults.reset()
            assert code == 0 and "room console stopped" in out and "Traceback" not in err, (code, out, err[-3000:])


@pytest.fixture(scope="module")
def page(desk):
    _, _, url, _ = desk
    with chromium("--autoplay-policy=no-user-gesture-required") as b:
        pg = b.new_page(viewport={"width": 1366, "height": 768})
        pg.goto(url + "scan")
        yield pg


def attr(page, selector, name):
    return page.eval_on_selector(selector, f"e => e.getAttribute({json.dumps(name)})")


def start(page, duration=None):
    page.fill("#reference", f"{REFERENCE_S:g}")
    page.fill("#duration", "" if duration is None else f"{duration:g}")
    page.click("#start")
    assert until(lambda: attr(page, "#scan", "data-phase") == "running", 60), page.inner_text("#message")


def post(page, path, body):
    """A POST from the page (its token), as its buttons make them: [status, error]."""
    return page.evaluate(
        """([path, body]) => fetch(path, {method: "POST", body: JSON.stringify(body),
        headers: {"Content-Type": "application/json", "X-Console-Token": document.getElementById("scan").dataset.token}})
        .then(r => r.json().then(d => [r.status, d.error]))""",
        [path, body],
    )


def trace_rate(page, band=1):
    """The breathing rate of the trace drawn on the page (its polylines: x s, y -mm)."""
    pts = page.eval_on_selector_all(
        f'.band[data-band="{band}"] svg polyline', "ls => ls.map(l => l.getAttribute('points'))"
    )
    xy = np.array([[float(v) for v in p.split(",")] for line in pts for p in line.split()])
    return _drawn_rate(xy[:, 0], -xy[:, 1]), xy


def _drawn_rate(t, v) -> float:
    """60 / the mean interval between rising crossings of the drawn trace's median (hysteresis a
    quarter of its 10-90 % range): the page shows 10 s, too few breaths seen whole for the
    analysis' rate (decision 0089), enough to see the drawn breaths come at the patient's pace."""
    lo, mid, hi = np.percentile(v, [10, 50, 90])
    side = np.where(v > mid + 0.25 * (hi - lo), 1, np.where(v < mid - 0.25 * (hi - lo), -1, 0))
    idx = np.flatnonzero(side)
    ups = t[idx[1:][(side[idx][1:] == 1) & (side[idx][:-1] == -1)]]
    return float(60.0 / np.mean(np.diff(ups))) if len(ups) >= 2 else float("nan")


def test_a_scan_from_the_page_records_shows_breathing_and_alerts_on_a_move(desk, page):
    rig, patient, url, scans = desk
    now = rig.clock.now()
    move = BodyMove(now + MOVE_AT_S, now + MOVE_AT_S + 0.6, (0.0, 1.0, 0.0), (2.0, 5.0, 2.0))
    patient.motion.moves.append(move)
    rig.prerender(DURATION_S + 6.0)
    start(page, DURATION_S)
    assert until(lambda: attr(page, "#status", "data-status") == "TRACKING", 30)
    assert "TRACKING" == page.inner_text("#status .word")
    assert attr(page, "#six", "data-known") == "yes"
    # the recording's pictures reach the page (fed by the recording: no second stream)
    assert until(lambda: attr(page, 'figure[data-camera="cam1"] img', "data-seq"), 10)
    assert rig.servers["cam1"].state()["active_streams"] == 1
    # the Room page, meanwhile, names the patient's markers as the live tracker does (chest 1 ...)
    room = page.context.browser.new_page(viewport={"width": 1366, "height": 768})
    room.goto(url)
    band_labels = lambda: room.eval_on_selector_all(  # noqa: E731
        'section[data-camera="cam1"] svg text.k-band', "ts => ts.map(t => t.textContent)"
    )
    assert until(lambda: len(band_labels()) >= 3, 30), band_labels()
    assert all(re.fullmatch(r"(chest|abdomen) \d+", t) for t in band_labels()), band_labels()
    assert rig.servers["cam1"].state()["active_streams"] == 1  # still the recording's one stream
    room.close()

    # the patient moves: a banner that stays, and the alarm sounding, until acknowledged
    page.wait_for_selector('.alert[data-kind="motion"]', timeout=30_000)
    assert "PATIENT MOVED" in page.inner_text('.alert[data-kind="motion"] .text')
    assert until(lambda: attr(page, "#alerts", "data-sound") == "played", 5)
    beeps = int(attr(page, "#alerts", "data-beeps"))
    assert until(lambda: int(attr(page, "#alerts", "data-beeps")) > beeps, 5)  # still sounding
    page.click('.alert[data-kind="motion"] button')
    assert until(lambda: attr(page, '.alert[data-kind="motion"]', "data-acked-by") == "local", 10)
    assert "acknowledged by local at" in page.inner_text('.alert[data-kind="motion"] .who')
    beeps = int(attr(page, "#alerts", "data-beeps"))
    time.sleep(2.0)
    assert int(attr(page, "#alerts", "data-beeps")) == beeps  # silent once acknowledged

    assert until(lambda: attr(page, "#scan", "data-phase") == "stopped", 60)
    # breathing: the trace drawn over the scan has the patient's rate
    rate, xy = trace_rate(page)
    assert len(xy) > 40 and np.ptp(xy[:, 0]) > 10.0 and np.ptp(xy[:, 1]) > 1.0  # 10 s and more, mm of breathing
    t_end = rig.clock.now()
    truth = np.nanmean([patient.breathing.rate_per_min(t) for t in np.arange(t_end - 15.0, t_end, 0.5)])
    assert abs(rate - truth) < 0.2 * truth, (rate, truth)

    # the recording: complete, whole, in a new folder of the scans folder; the page says so
    (session,) = [p for p in scans.iterdir() if p.name.startswith("scan-")]
    m = json.loads((session / "manifest.json").read_text())
    assert m["status"] == "complete" and m["scan"]["stop_reason"] == "duration"
    for name, cam in m["cameras"].items():
        assert cam["dropped_frames"] == 0 and cam["gaps"] == []
        assert len(read_index(session / f"{name}.index.csv")) == cam["frames"] >= 0.9 * 25 * DURATION_S
    assert len(m["live_motion"]["alerts"]) == 1
    assert attr(page, "#scan", "data-recording") == "complete"
    assert "status complete" in page.inner_text("#summary")
    acts = requests.get(url + "scan/state", timeout=10).json()["actions"]
    ack = [a for a in acts if a["what"] == "alert acknowledged"]
    assert len(ack) == 1 and ack[0]["user"] == "local" and "PATIENT MOVED" in ack[0]["detail"]["alert"]
    assert {"scan started", "alert acknowledged"} <= {a["what"] for a in acts}

    # one click: the motion analysis, its report served from the scan folder and nothing outside it
    page.click("#analyse")
    assert until(lambda: attr(page, "#analysis", "data-state") in ("done", "failed"), 240)
    assert attr(page, "#analysis", "data-state") == "done", page.inner_text("#analysis")
    report = page.eval_on_selector("#report", "e => e.href")
    got = requests.get(report, timeout=10)
    assert got.status_code == 200 and b"<html" in got.content[:500].lower()
    assert (session / "motion" / "motion-report.html").read_bytes() == got.content
    assert (session / "motion" / "export" / "motion_6dof.csv").exists()
    assert "stored: run" in page.inner_text("#analysis")
    for bad in (
        f"scan/files/{session.name}/../../rig/rig.yaml",
        f"scan/files/{session.name}/..%2F..%2Frig%2Frig.yaml",
        "scan/files/..%2Frig/rig.yaml",
        f"scan/files/{session.name}/nothing.txt",
    ):
        assert requests.get(url + bad, timeout=10).status_code == 404, bad


def test_a_camera_switched_off_is_not_tracking_and_the_scan_partial(desk, page):
    rig, _, url, scans = desk
    rig.prerender(16.0)
    start(page)
    assert until(lambda: attr(page, "#status", "data-status") == "TRACKING", 30)
    # while it runs: a second start, a bad reference, an alert that does not exist: one sentence each
    assert post(page, "/scan/start", {}) == [
        409,
        "a scan is already running (" + attr(page, "#scan", "data-folder") + "): stop it first",
    ]
    assert post(page, "/scan/start", {"reference_s": "ten"})[0] == 400
    assert post(page, "/scan/alert/99/ack", {}) == [404, "no alert '99' in this scan"]
    assert post(page, "/scan/analyse", {}) == [409, "no finished scan to analyse"]
    rig.servers["cam2"].go_offline(5.0)
    seen = []

    def sample():
        s = page.eval_on_selector(
            "#scan",
            """e => [e.dataset.status, document.querySelector('#status .reason').textContent,
            document.querySelector('#six').dataset.known,
            [...document.querySelectorAll('.band')].map(b => b.dataset.known).join(','),
            document.querySelector('#six').innerText]""",
        )
        seen.append(s)
        return s[0] == "NOT TRACKING" and "camera lost" in s[1] and "cam2" in s[1]

    assert until(sample, 15, poll=0.1), seen[-3:]
    page.wait_for_selector('.alert[data-kind="not tracking"]', timeout=15_000)
    assert "PATIENT NOT TRACKED" in page.inner_text('.alert[data-kind="not tracking"] .text')
    # while it is not tracked, no figure is shown as known
    blind = [s for s in seen if s[0] == "NOT TRACKING"]
    assert blind and all(s[2] == "no" and "yes" not in s[3] and "NOT KNOWN" in s[4] for s in blind), blind[-3:]
    page.click("#stop")
    assert until(lambda: attr(page, "#scan", "data-phase") == "stopped", 60)
    assert attr(page, "#scan", "data-recording") == "partial"
    text = page.inner_text("#after")
    assert "PARTIAL" in text and "camera cam2:" in text and "missing" in text
    acts = requests.get(url + "scan/state", timeout=10).json()["actions"]
    assert [a["what"] for a in acts].count("scan stopped") == 1
