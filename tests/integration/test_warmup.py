"""The daily QA reads each camera's uptime over VAPIX (systemready.cgi on current firmware, the
server report's busybox uptime line on the AXIS 211) and says of a camera started less than its
warm-up time ago that its drift may not have settled; the stored run records it and the drift
report marks the run."""

from __future__ import annotations

import pytest

from qa_runs import baselines_now, run_qa
from vts_hw.config import parse_rig
from vts_hw.drivers.axis import AxisCamera
from vts_hw.drivers.axis_uptime import NoUptime, parse_busybox_uptime
from vts_hw.drivers.registry import open_camera
from vts_hw.procedures.daily import QARun
from vts_hw.report.build import build_drift_report
from vts_hw.sim_devices.rig import SimRig
from vts_hw.store import ResultsStore


@pytest.fixture
def room(tmp_path):
    with SimRig(n_cameras=2, seed=7, firmware=["p1375", "axis211"]) as rig, rig.env():
        data = rig.config().model_dump(mode="json", exclude_none=True)
        data["store"] = {"url": f"sqlite:///{tmp_path / 'results.sqlite'}"}
        data["cameras"][1]["warmup_min"] = 45
        yield rig, parse_rig(data, "test rig")


def test_uptime_of_each_model_as_its_firmware_tells_it(room):
    rig, cfg = room
    rig.servers["cam1"].booted_at = rig.clock.now() - 754.4  # 12 min 34 s
    rig.servers["cam2"].booted_at = rig.clock.now() - (2 * 86400 + 3 * 3600 + 5 * 60 + 59)
    with AxisCamera.from_config(cfg.camera("cam1")) as cam:
        up = cam.uptime()
    assert (up.seconds, up.resolution_s, up.method) == (754.0, 1.0, "systemready.cgi")
    with AxisCamera.from_config(cfg.camera("cam2")) as cam:
        up = cam.uptime()
    assert (up.seconds, up.resolution_s, up.method) == ((2 * 1440 + 3 * 60 + 5) * 60.0, 60.0, "serverreport.cgi")


@pytest.mark.parametrize(
    "line, seconds",
    [
        (" 10:15:21 up 3 days,  2:01, load average: 0.0", 3 * 86400 + 121 * 60),
        (" 10:15:21 up 12 min, load average: 0.0", 720),
        ("up 1 day, 0 min,", 86400),
        ("up  0:07,", 420),
        ("no such line", None),
        ("setup 5 min", None),
    ],
)
def test_busybox_uptime_lines(line, seconds):
    assert parse_busybox_uptime(line) == seconds


def test_a_camera_started_minutes_ago_is_said_stored_and_marked_in_the_drift_report(room, tmp_path):
    rig, cfg = room
    rig.servers["cam2"].booted_at = rig.clock.now() - 20 * 60  # the AXIS 211: 20 of its 45 min
    with ResultsStore(cfg.store.url) as store:
        baselines_now(cfg, store)
        result = run_qa(cfg, store, n_frames=2, open_camera=open_camera)
        assert result.run_id is not None and result.store_error is None
        by_cam = {c.camera: c for c in result.cameras}
        assert (
            "started 20 min ago, less than its warm-up time (45 min): its drift may not have settled "
            "(about 25 min to go)"
        ) in by_cam["cam2"].problems
        assert not any("warm-up" in p for p in by_cam["cam1"].problems)  # a day up: settled
        stored = {(m.subject, m.metric): m.value for m in store.measurements(run_id=result.run_id)}
        assert stored[("cam2", "warming_up")] == 1.0 and stored[("cam1", "warming_up")] == 0.0
        assert stored[("cam2", "uptime_min")] == pytest.approx(20.0, abs=1.0)
        assert stored[("cam1", "uptime_min")] >= 24 * 60
        html = tmp_path / "drift.html"
        build_drift_report(store, html)
    text = html.read_text()
    assert text.count(">warming up</span>") == 1  # the one run of cam2, and no other
    assert "camera warming up</b>: 1 run(s)" in text
    assert "its drift may not have settled" in result.results()  # what `vts qa daily` prints


def test_a_camera_that_tells_no_uptime_is_not_known_never_warm(room):
    rig, cfg = room
    srv = rig.servers["cam2"]
    srv.profile = type(srv.profile)(
        **{**srv.profile.__dict__, "cgis": srv.profile.cgis - {"/axis-cgi/admin/serverreport.cgi"}}
    )
    with AxisCamera.from_config(cfg.camera("cam2")) as cam, pytest.raises(NoUptime):
        cam.uptime()
    result = QARun(cfg, steps=("reachable",), open_camera=open_camera).run()
    cam2 = next(c for c in result.cameras if c.camera == "cam2")
    assert [m.metric for m in cam2.measures] == ["camera_reachable"]  # nothing stored as if known
    assert any(
        p.startswith("uptime not known (camera cam2 tells no uptime") and "not known" in p for p in cam2.problems
    ), cam2.problems
    assert str(cam2.state) == "OK"
