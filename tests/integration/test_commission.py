"""`vts commission` on the simulated rig (issue 24 §3): two cameras announcing themselves on
loopback, the trigger-box firmware in the emulator, the 7-sphere phantom on the table. The
sequence stops at a mis-aimed camera with what to do, resumes once it is turned back, stops again
where the sync check needs a scan, resumes with the scan, and ends with the report (HTML in a
real Chromium, PDF), stored as a run, and the rooms page saying "commissioned on"."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import cv2
import pytest

from inprocess_cli import vts
from vts_hw.config import dump_rig, load_rig
from vts_hw.sim_devices import checkerboard as cb
from vts_hw.sim_devices.rig import SimRig
from vts_hw.store import ResultsStore

CHROMIUM = "/usr/bin/chromium"


def _boards(rig, folder: Path, n: int = 12) -> Path:
    """The checkerboard views the operator takes once the cameras are aimed (cam1/sim01.png ...)."""
    pairs, names = cb.render_pairs(rig.scene, n=n, seed=1, t=rig.clock.now())
    for (left, right), name in zip(pairs, names):
        for cam, img in (("cam1", left), ("cam2", right)):
            (folder / cam).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(folder / cam / f"{name}.png"), img)
    return folder


class Operator:
    """The person at the table: moves the simulated table to the position the step test asks
    for, and the simulated SPECT images it into the volumes folder."""

    def __init__(self, rig, volumes: Path, vertical: int, axial: int):
        from vts_hw.procedures.steps import step_plan
        from vts_hw.sim_devices.step_table import SimSpectSource, SimTable

        self.plan = {p.label: p for p in step_plan(vertical, axial)}
        self.table = SimTable(rig.scene, rig.clock.now, seed=2)
        self.spect = SimSpectSource(rig.scene, rig.clock.now, volumes, seed=2)
        self.asked: list[str] = []

    def __call__(self, text: str):
        self.asked.append(text)
        m = re.match(r"\[(\w+)\]", text)
        if m and m.group(1) in self.plan:
            pos = self.plan[m.group(1)]
            self.table.move_to(pos)
            self.spect.acquired(pos)
        return ""


@pytest.fixture()
def room(tmp_path):
    rig = SimRig(n_cameras=2, seed=4, trigger="triggerbox", announce=True, optics={"cam2": {"yaw_deg": 6.0}}).start()
    try:
        rig.ntp_sync()
        rig.scene.add_phantom()
        rig_yaml = tmp_path / "rig.yaml"
        store = f"sqlite:///{tmp_path / 'results.sqlite'}"
        # the warm-up watched for a second (3 samples): this room runs in real time, where a second cannot
        # tell 0.05 px/min from noise (a few px/min), so its limit is loose; the warm-up's judgement is
        # tests/integration/test_commission_warmup.py's, on a clock that runs fast
        rig_yaml.write_text(
            "# room 1, as `vts discover -o rig.yaml` wrote it\n"
            + dump_rig(rig.config(rig_name="room1", results_url=store))
            + "warmup: {interval_s: 0.4, samples: 3, frames: 1}\n"
            "tolerances: {warmup_rate_px_min: {tolerance_high: 5, unit: px/min}}\n"
        )
        with rig.env():
            yield rig, rig_yaml, store
    finally:
        rig.stop()


def test_commissioning_stops_at_a_mis_aimed_camera_resumes_and_ends_with_the_report(
    room, tmp_path, capsys, monkeypatch
):
    from vts_hw.sim_devices.scenarios import sync_session as sync_sim

    rig, rig_yaml, store_url = room
    out = tmp_path / "commission"
    base = [
        "commission",
        "--config",
        rig_yaml,
        "-o",
        out,
        "--listen",
        "1",
        "--interface",
        "127.0.0.1",
        "--frames",
        "2",
        "--vertical",
        "1",
        "--axial",
        "1",
    ]

    # 1. cam2's mount is turned: the aim step stops the sequence with the way to turn it
    code, so, se = vts(capsys, *base)
    assert code == 10, se
    assert "commissioning stopped at aim and focus" in so and re.search(
        r"cam2 aim: aim (about )?\d+\.\d° (left|right)", so
    ), so
    assert "locked_params written" in se and "firmware" in se and "announced: " in se
    assert "locked_params:" in rig_yaml.read_text() and "# room 1" in rig_yaml.read_text()  # comments kept

    # 2. turned back; the operator takes the checkerboard views and the SPECT images the phantom
    rig.sources["cam2"].set_optics(yaw_deg=0.0)
    boards = _boards(rig, tmp_path / "boards")
    from vts_hw.sim_devices.spect import SimSpect
    from vts_hw.sim_devices.step_table import SPECT_MATRIX, sphere_centres

    phantom = SimSpect(matrix=SPECT_MATRIX, seed=7).write(
        tmp_path / "phantom.npz", sphere_centres(rig.scene, rig.clock.now())
    )
    operator = Operator(rig, tmp_path / "volumes", 1, 1)
    monkeypatch.setattr("vts_hw.cli.commission._ask", operator)
    inputs = [
        "--checkerboards",
        boards,
        "--square",
        cb.SQUARE_MM,
        "--phantom-volume",
        phantom,
        "--step-volumes",
        tmp_path / "volumes",
    ]
    code, so, se = vts(capsys, *base, "--resume", *inputs)
    assert code == 2, se  # the sync check needs a scan: said, with how
    assert "needs --sync-session DIR and --listmode FILE" in se and "vts scan start" in se
    assert "== discover and set up" not in se and "== aim and focus" in se  # resumed after the last good step
    assert [a[:10] for a in operator.asked] == ["[baseline]", "[V01] Rais", "[A01] Move", "[free] Tur"]
    cal = load_rig(rig_yaml).calibration  # what the step test, scans and `vts camera aim` now read
    assert (cal.cameras, cal.mapping) == (out / "calibration.json", out / "spect_mapping.json")
    assert rig_yaml.read_text().startswith("# room 1")

    # 3. the scan with a source marker moved; then resume: sync check, baseline, the report
    marker = sync_sim.prepare(rig)
    scan = sync_sim.cli_scan(rig, rig_yaml, tmp_path / "scan", 14.0, marker, n=2, seed=1)
    code, so, se = vts(
        capsys,
        *base,
        "--resume",
        *inputs,
        "--sync-session",
        scan.session,
        "--listmode",
        scan.listmode,
        "--sign-off",
        "A. Physicist",
    )
    assert code in (0, 10), se
    assert "== sync check" in se and "== drift baseline" in se and "== step test" not in se
    html, pdf = out / "commissioning.html", out / "commissioning.pdf"
    assert html.is_file() and pdf.read_bytes()[:5] == b"%PDF-"

    with ResultsStore(store_url) as store:
        from vts_hw.store.commission import load_state

        state = load_state(store, "room1")
        assert set(state.steps) == {
            "cameras",
            "trigger",
            "aim",
            "warmup",
            "calibration",
            "mapping",
            "steps",
            "sync",
            "baseline",
        }
        assert all(s.passed for s in state.steps.values())
        aims = [r for r in store.runs("commission-step") if "step aim" in r.notes]
        assert [("stopped" in r.notes) for r in aims] == [True, False]  # the failed run stays in history
        assert {store.run(s.step_run).procedure for s in state.steps.values() if s.step_run} == {
            "calibration",
            "spect_mapping",
            "sphere-steps",
            "sync",
            "drift-baseline",
        }
        report_run = store.run(state.report_run)
        assert report_run.procedure == "commissioning" and report_run.operator == "A. Physicist"
        assert {Path(a.path).name for a in store.artifacts(report_run.id)} == {
            "commissioning.html",
            "commissioning.pdf",
        }
        status = report_run.status

    _check_pdf(pdf)
    _check_in_browser(html, status)
    code, so, se = vts(capsys, "--store", store_url, "report", "rooms", "-o", tmp_path / "rooms.html")
    page = (tmp_path / "rooms.html").read_text()
    assert "commissioned on" in page and "signed off by A. Physicist" in page, se


def _check_pdf(pdf: Path) -> None:
    import subprocess

    if shutil.which("pdfinfo") is None:
        pytest.fail("pdfinfo (poppler-utils) is needed: make debs")
    info = subprocess.run(["pdfinfo", str(pdf)], capture_output=True, text=True, check=True).stdout
    pages = int(re.search(r"Pages:\s+(\d+)", info).group(1))
    assert 1 <= pages <= 6, info
    from test_report_faults import assert_pdf_fits

    assert_pdf_fits(pdf, overlap_pages=range(pages))  # nothing drawn over anything else
    text = subprocess.run(["pdftotext", str(pdf), "-"], capture_output=True, text=True, check=True).stdout
    assert "Signed off by A. Physicist" in text and "Devices" in text and "step test" in text


def _check_in_browser(html: Path, status: str) -> None:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            page = browser.new_page()
            page.goto(html.resolve().as_uri())
            assert page.get_attribute("body", "data-state") == status
            assert page.locator("tr.step").count() == 9
            states = page.locator("tr.step").evaluate_all("rs => rs.map(r => r.dataset.state)")
            assert set(states) <= {"OK", "TOLERANCE"}, states
            assert page.locator("#signoff").inner_text().startswith("Signed off by A. Physicist")
            assert page.locator("tr[data-camera]").count() == 2
            verdict = page.locator("#verdict").inner_text()
            assert status in verdict and ("within tolerance" in verdict or "review" in verdict)
            assert page.locator("tr.figure").count() > 10
        finally:
            browser.close()
