"""The daily QA set against the simulated rig over HTTP, through the store and the CLI.
The store-using tests run on SQLite and on PostgreSQL (conftest.store_url)."""

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time

import pytest
import yaml

from inprocess_cli import run
from qa_runs import run_qa, save_baselines
from vts_hw.config import parse_rig
from vts_hw.drivers.registry import open_camera
from vts_hw.procedures.drift import acquire_led_frames
from vts_hw.store import ResultsStore
from vts_hw.store.baselines import load_baseline
from vts_hw.tolerance import State
from vts_hw.vision.wall_baseline import NoBaseline
from vts_hw.vision.wall_markers import baseline_from_frames

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


def _cfg(sim_rig, url):
    data = sim_rig.config().model_dump(mode="json", exclude_none=True)
    data["store"] = {"url": url}
    return parse_rig(data, "test rig")


@pytest.fixture()
def rig_cfg(sim_rig, store_url):
    return _cfg(sim_rig, store_url)


@pytest.fixture()
def sqlite_rig_cfg(sim_rig, tmp_path):
    return _cfg(sim_rig, f"sqlite:///{tmp_path / 'results.sqlite'}")


@pytest.fixture()
def store(rig_cfg):
    with ResultsStore(rig_cfg.results.url) as s:
        yield s


def _baseline(rig_cfg, store):
    bs = []
    for c in rig_cfg.cameras:
        with open_camera(c) as cam:
            on, _ = acquire_led_frames(cam, 3)
        bs.append(baseline_from_frames(c.name, [s.jpeg for s in on], time.time()))
    return save_baselines(store, bs, rig=rig_cfg.rig)


def test_daily_set_all_ok_and_stored(rig_cfg, store, tmp_path):
    with pytest.raises(NoBaseline, match="set-baseline"):
        load_baseline(store, "cam1")
    _baseline(rig_cfg, store)
    assert len(load_baseline(store, "cam2").markers) == 5
    res = run_qa(rig_cfg, store, open_camera=open_camera, n_frames=3, artifacts_dir=tmp_path / "art", plots=True)
    assert res.state == State.OK and res.exit_code == 0, res.results()
    run = store.run(res.run_id)
    assert run.procedure == "daily" and run.status == "OK"
    rows = store.measurements(run_id=res.run_id)
    metrics = {(m.subject, m.metric) for m in rows}
    for cam in ("cam1", "cam2"):
        for metric in (
            "camera_reachable",
            "params_changed",
            "clock_offset_s",
            "drift_x_px",
            "drift_y_px",
            "drift_x_mm",
            "led_off_visible",
            "markers_missing",
            "stray_blobs",
        ):
            assert (cam, metric) in metrics
    judged = [m for m in rows if m.metric == "drift_x_px"]
    assert all(m.tolerance_id is not None for m in judged)  # the window in effect is kept with the value
    arts = store.artifacts(res.run_id)
    assert {a.kind for a in arts} == {"frame", "plot"} and len(arts) == 7
    assert all(os.path.exists(a.path) for a in arts)
    overview = [a.path for a in arts if os.path.basename(a.path) == "daily.png"]
    assert len(overview) == 1 and open(overview[0], "rb").read(8) == b"\x89PNG\r\n\x1a\n"


def test_changed_parameter_and_dead_camera_are_actions(rig_cfg, store, sim_rig):
    _baseline(rig_cfg, store)
    sim_rig.servers["cam1"].params.update([("Image.I0.Appearance.Compression", "60")])
    sim_rig.servers["cam2"].stop()
    res = run_qa(rig_cfg, store, open_camera=open_camera, n_frames=2)
    by_cam = {c.camera: c for c in res.cameras}
    assert res.state == State.ACTION and res.exit_code == 20
    # the overview says which camera is in which state, and why, where a person looks
    from vts_hw.procedures.daily_plot import daily_figure

    fig = daily_figure(res, res.windows)
    assert [ax.get_title() for ax in fig.axes] == ["cam1: ACTION", "cam2: ACTION"]
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    assert any("params_changed 1" in t and "ACTION" in t for t in texts)
    assert any("no drift" in t for t in texts)
    assert res.plot()[:8] == b"\x89PNG\r\n\x1a\n"
    assert any("Compression is '60', locked at '25'" in p for p in by_cam["cam1"].problems)
    assert by_cam["cam1"].drift is not None and by_cam["cam1"].drift.missing == []
    assert ("cam2", "camera_reachable", 0.0) in [(s, m, v) for s, m, v, _, _ in by_cam["cam2"].measures]
    assert "unreachable" in " ".join(by_cam["cam2"].problems)
    assert store.run(res.run_id).status == "ACTION"


def test_tolerance_change_never_rewrites_history(rig_cfg, store):
    from vts_hw.tolerance import Window

    _baseline(rig_cfg, store)
    first = run_qa(rig_cfg, store, open_camera=open_camera, n_frames=2, steps=("drift",))
    assert first.state == State.OK
    tight = rig_cfg.model_copy(update={"tolerances": {"drift_x_px": Window.symmetric(0.0, 0.0, "px")}})
    second = run_qa(tight, store, open_camera=open_camera, n_frames=2, steps=("drift",))
    assert second.state == State.ACTION
    assert store.run(first.run_id).status == "OK"
    old = [m for m in store.measurements(run_id=first.run_id) if m.metric == "drift_x_px" and m.subject == "cam1"]
    assert old[0].status == "OK"


def _cli_env(sim_rig, rig_cfg, tmp_path):
    cfg_path = tmp_path / "rig.yaml"
    cfg_path.write_text(yaml.safe_dump(rig_cfg.model_dump(mode="json", exclude_none=True)))
    env = dict(os.environ, VTS_CONFIG=str(cfg_path))
    env.update(sim_rig.env_vars())
    return env


def test_cli_baseline_daily_report_and_exit_codes(sim_rig, sqlite_rig_cfg, tmp_path):
    rig_cfg = sqlite_rig_cfg
    env = _cli_env(sim_rig, rig_cfg, tmp_path)

    def vts(*a):
        return run(*a, env=env)  # in this process (tests/inprocess_cli.py)

    p = vts("qa", "daily", "--dry-run")
    assert p.returncode == 0 and "LED on" in p.stdout and not (tmp_path / "results.sqlite").exists()
    p = vts("qa", "drift")
    assert p.returncode == 5 and "--set-baseline" in p.stderr and "Traceback" not in p.stderr
    p = vts("qa", "drift", "--set-baseline")
    assert p.returncode == 0 and "cam2: baseline of 5 markers" in p.stdout, p.stderr
    p = vts("qa", "daily", "--json")
    assert p.returncode == 0, p.stdout + p.stderr
    data = json.loads(p.stdout)
    assert data["state"] == "OK" and {c["camera"] for c in data["cameras"]} == {"cam1", "cam2"}
    sim_rig.sources["cam2"].set_led(True)
    sim_rig.servers["cam2"].params.update([("Image.I0.Stream.FPS", "12")])
    p = vts("qa", "daily")
    assert p.returncode == 20 and "ACTION" in p.stdout
    p = vts("report", "drift", "-o", str(tmp_path / "r.html"))
    assert p.returncode == 0 and (tmp_path / "r.html").stat().st_size > 10000, p.stderr
    p = vts("report", "drift", "--since", "yesterday-ish", "-o", str(tmp_path / "r.html"))
    assert p.returncode == 2 and "--since" in p.stderr
    assert sim_rig.password not in (tmp_path / "r.html").read_text()


def test_kill_9_during_a_qa_run_leaves_it_aborted(sim_rig, rig_cfg, store, tmp_path):
    _baseline(rig_cfg, store)
    env = _cli_env(sim_rig, rig_cfg, tmp_path)
    proc = subprocess.Popen(
        [*VTS, "qa", "daily", "--frames", "20"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        deadline = time.monotonic() + 30
        running = None
        while time.monotonic() < deadline and running is None:
            running = [r.id for r in store.runs(status="running")] or None
            time.sleep(0.02)
        assert running is not None, "the QA run never started"
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    with ResultsStore(rig_cfg.results.url) as again:
        run = again.run(running[0])
        assert run.status == "aborted"
        assert again.measurements(run_id=run.id) == []
    if rig_cfg.store.url.startswith("sqlite:///"):
        con = sqlite3.connect(rig_cfg.store.url[len("sqlite:///") :])
        assert con.execute("pragma integrity_check").fetchone()[0] == "ok"
