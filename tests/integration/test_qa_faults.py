"""`vts qa daily` when the setup is wrong or the store cannot be written: setup mistakes write
nothing to the QA history; a full store never costs a measured figure."""

import json
import os
import subprocess
import sys

import pytest
import yaml

from inprocess_cli import run
from qa_runs import baselines_now, run_qa
from vts_hw.config import parse_rig
from vts_hw.drivers.registry import open_camera
from vts_hw.sim_devices.rig import SimRig
from vts_hw.store import ResultsStore

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


def vts(env, *args):
    """`vts ARGS` in this process (tests/inprocess_cli.py) with the environment ``env``."""
    return run(*args, env=env)


@pytest.fixture()
def rig(tmp_path):
    with SimRig(n_cameras=2, seed=5) as r, r.env():
        yield r


def _setup(r, folder, store_url, extra=None):
    """rig.yaml for the sim with its store at ``store_url``; env with the passwords."""
    folder.mkdir(parents=True, exist_ok=True)
    data = r.config().model_dump(mode="json", exclude_none=True)
    data["results"] = {"url": store_url}
    data.update(extra or {})
    (folder / "rig.yaml").write_text(yaml.safe_dump(data))
    env = dict(os.environ, **r.env_vars(), VTS_CONFIG=str(folder / "rig.yaml"), XDG_DATA_HOME=str(folder / "xdg"))
    return (parse_rig(data, "test") if not extra else None), env


def _daily_breaking_the_store(env, breaks):
    """`vts qa daily` in a subprocess; ``breaks()`` is called once the run's row is written and
    the cameras are being measured. Returns (exit status, stdout, stderr)."""
    proc = subprocess.Popen(
        [*VTS, "qa", "daily", "--frames", "2"], env=env, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    err = []
    for line in proc.stderr:
        err.append(line)
        if "cam1: checking" in line:
            breaks()
            break
    out, rest = proc.communicate(timeout=120)
    return proc.returncode, out, "".join(err) + rest


def _runs(url):
    with ResultsStore(url) as s:
        return [(r.procedure, r.status) for r in s.runs()]


def test_setup_mistakes_are_exit_2_and_write_nothing(rig, tmp_path):
    url = f"sqlite:///{tmp_path / 'r.sqlite'}"
    cfg, env = _setup(rig, tmp_path / "a", url)
    with ResultsStore(url) as s:
        baselines_now(cfg, s)
    before = _runs(url)
    unset = dict(env)
    del unset["VTS_SIM_CAM2_PASSWORD"]
    p = vts(unset, "qa", "daily")
    assert p.returncode == 2 and "VTS_SIM_CAM2_PASSWORD" in p.stderr and "Traceback" not in p.stderr
    p = vts(env, "qa", "daily", "--camera", "cam9")
    assert p.returncode == 2 and "cam9" in p.stderr
    p = vts(unset, "qa", "drift", "--set-baseline")
    assert p.returncode == 2 and "VTS_SIM_CAM2_PASSWORD" in p.stderr
    assert _runs(url) == before  # nothing in the QA history


def test_unknown_tolerance_metric_is_a_config_error(rig, tmp_path):
    _, env = _setup(
        rig,
        tmp_path / "a",
        f"sqlite:///{tmp_path / 'r.sqlite'}",
        {"tolerances": {"drift_z_px": {"tolerance_high": 1.0}}},
    )
    p = vts(env, "qa", "daily")
    assert p.returncode == 2 and "drift_z_px" in p.stderr and "rig.yaml" in p.stderr
    assert not (tmp_path / "r.sqlite").exists()


def test_no_baseline_is_exit_5_and_writes_no_aborted_run(rig, tmp_path):
    url = f"sqlite:///{tmp_path / 'r.sqlite'}"
    _, env = _setup(rig, tmp_path / "a", url)
    p = vts(env, "qa", "daily")
    assert p.returncode == 5 and "set-baseline" in p.stderr and "NoBaseline" not in p.stderr
    assert _runs(url) == []


def test_full_store_keeps_every_figure_and_imports_later(rig, tmp_path, small_disk):
    disk = small_disk(2048)
    url = f"sqlite:///{disk.path / 'results.sqlite'}"
    cfg, env = _setup(rig, tmp_path / "a", url)
    with ResultsStore(url) as s:
        baselines_now(cfg, s)
    # the disk fills up while the cameras are being measured (the run's row is written by then)
    code, out, stderr = _daily_breaking_the_store(env, lambda: disk.fill(leave=0))
    assert code == 3, stderr
    assert "NOT stored" in stderr and "vts qa import" in stderr and "Traceback" not in stderr
    assert "drift_x_px" in out  # the figures are printed
    unsaved = stderr.split("are above and in ")[1].split(" (")[0]
    data = json.loads(open(unsaved).read())["results"]
    assert data["run_id"] is None and "cannot write to the results store" in data["store_error"]
    figures = {(m["subject"], m["metric"]) for c in data["cameras"] for m in c["measurements"]}
    assert ("cam1", "drift_x_px") in figures and ("cam2", "clock_offset_s") in figures
    assert unsaved.startswith(str(tmp_path / "a" / "xdg"))  # the store's own disk is full
    saved = json.loads(open(unsaved).read())
    assert len(saved["measurements"]) >= 2 * 9
    # room again: the runs left "running" are marked aborted, the figures go in as the run they were
    disk.free_up()
    p = vts(env, "qa", "import", unsaved)
    assert p.returncode == 0, p.stderr
    with ResultsStore(url) as s:
        left, runs = s.runs(procedure="daily")
        assert left.status == "aborted" and s.measurements(run_id=left.id) == []  # the row left "running"
        assert runs.status == data["state"] and "imported from" in runs.notes
        stored = {(m.subject, m.metric, m.value) for m in s.measurements(run_id=runs.id)}
        assert runs.started == pytest.approx(data["started"])
    assert {(m["subject"], m["metric"], m["value"]) for m in saved["measurements"]} == stored
    assert os.path.exists(unsaved + ".imported") and not os.path.exists(unsaved)
    assert vts(env, "qa", "import", unsaved).returncode == 2  # never stored twice


def test_store_full_at_the_end_of_the_run(rig, tmp_path, small_disk):
    """The run's row was written, then the disk filled while the cameras were measured."""
    disk = small_disk(2048)
    url = f"sqlite:///{disk.path / 'results.sqlite'}"
    cfg, _ = _setup(rig, tmp_path / "a", url)
    with ResultsStore(url) as s:
        baselines_now(cfg, s)
        filled = []

        def progress(msg):
            if not filled:
                disk.fill(leave=0)
                filled.append(msg)

        res = run_qa(
            cfg, s, open_camera=open_camera, n_frames=2, artifacts_dir=disk.path / "artifacts", progress=progress
        )
    assert filled and res.run_id is None and "cannot write" in res.store_error
    assert {c.camera for c in res.cameras} == {"cam1", "cam2"}
    assert any(m[1] == "drift_x_px" for c in res.cameras for m in c.measures)
    assert all("frames not saved" in " ".join(c.problems) for c in res.cameras)
    disk.free_up()
    with ResultsStore(url) as s:  # the run left "running" by this (living) process stays so
        assert [r.status for r in s.runs(procedure="daily")] in (["running"], ["aborted"])


def test_postgresql_gone_during_the_run_keeps_every_figure_and_imports_later(rig, tmp_path, pg_server):
    """The department's PostgreSQL store lets the run's row in, then shuts its door while the
    cameras are measured (its connections ended, no new ones let in): the figures survive."""
    db = pg_server.new_database()
    url = pg_server.url(db)
    cfg, env = _setup(rig, tmp_path / "a", url)
    with ResultsStore(url) as s:
        baselines_now(cfg, s)
    with pg_server.admin() as con:

        def shut():
            con.execute(f'ALTER DATABASE "{db}" WITH ALLOW_CONNECTIONS false')
            con.execute("SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE datname = %s", (db,))

        code, out, stderr = _daily_breaking_the_store(env, shut)
        assert code == 3, stderr
        assert "NOT stored" in stderr and "vts qa import" in stderr and "Traceback" not in stderr
        assert "drift_x_px" in out
        unsaved = stderr.split("are above and in ")[1].split(" (")[0]
        saved = json.loads(open(unsaved).read())
        figures = {(m["subject"], m["metric"]) for m in saved["measurements"]}
        assert ("cam1", "drift_x_px") in figures and ("cam2", "drift_x_px") in figures
        con.execute(f'ALTER DATABASE "{db}" WITH ALLOW_CONNECTIONS true')
    try:
        p = vts(env, "qa", "import", unsaved)
        assert p.returncode == 0, p.stderr
        with ResultsStore(url) as s:
            stored = {
                (m.subject, m.metric, m.value) for r in s.runs(procedure="daily") for m in s.measurements(run_id=r.id)
            }
        assert {(m["subject"], m["metric"], m["value"]) for m in saved["measurements"]} == stored
    finally:
        pg_server.drop_database(db)
