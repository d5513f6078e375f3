"""Pushes into the real QATrack+ 3.1 (../shared/interop/qatrack/run-qatrack.sh), read back
through its own API: every value under its test, the work times at their true instants (to the
second) in three site time zones (one south of the equator) and around their clock changes,
the comment, the attachments; no duplicate after a second push or a push from a copy of the
store; nothing lost when the server stops mid-push. The server starts in the background when
the session's tests are collected and these tests run last (tests/qatrack_real.py)."""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import re
import shutil
import subprocess
import sys
from zoneinfo import ZoneInfo

import pytest
import requests

from vts_hw.config import parse_rig
from vts_hw.qatrack import exit_code, push_runs, run_key, select_runs
from vts_hw.store import ResultsStore

pytestmark = [pytest.mark.real_qatrack, pytest.mark.xdist_group("real_qatrack"), pytest.mark.timeout(900)]

UNIT, LIST = "SPECT room 1", "VTS daily"
MACROS = {
    "cam1/drift_x_px": "cam1_dx",
    "cam1/drift_y_px": "cam1_dy",
    "cam2/drift_x_px": "cam2_dx",
    "cam2/drift_y_px": "cam2_dy",
    "cam1/drift_sd_px": "cam1_sd",
    "cam2/drift_sd_px": "cam2_sd",
    "cam1/markers_missing": "cam1_missing",
    "cam2/markers_missing": "cam2_missing",
    "cam3/drift_x_px": "cam3_dx",
}
VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


def qatrack_cfg(site, zone: str, **over) -> dict:
    q = {
        "url": site.url,
        "unit": UNIT,
        "time_zone": zone,
        "token_env": "QATRACK_TOKEN",
        "timeout_s": 30,
        "report": "none",
        "plots": False,
        "lists": {"daily": {"test_list": LIST, "macros": dict(MACROS), "ignore": ["*/M*/*"]}},
    }
    q.update(over)
    return q


def rig(site, zone: str, **over):
    return parse_rig(
        {
            "rig": "room1",
            "cameras": [{"name": "cam1", "host": "127.0.0.1"}],
            "qatrack": qatrack_cfg(site, zone, **over),
        },
        "test rig",
    ).qatrack


def transitions(zone: str, year: int = 2026) -> list[tuple[float, _dt.timedelta]]:
    """(UTC epoch s, offset change) of the zone's clock changes in ``year``."""
    z, out = ZoneInfo(zone), []
    t = _dt.datetime(year, 1, 1, tzinfo=_dt.UTC).timestamp()
    end = _dt.datetime(year + 1, 1, 1, tzinfo=_dt.UTC).timestamp()
    off = _dt.datetime.fromtimestamp(t, z).utcoffset()
    while t < end:
        nxt = _dt.datetime.fromtimestamp(t + 3600, z).utcoffset()
        if nxt != off:
            lo, hi = t, t + 3600
            while hi - lo > 1:
                mid = (lo + hi) // 2
                lo, hi = (mid, hi) if _dt.datetime.fromtimestamp(mid, z).utcoffset() == off else (lo, mid)
            out.append((hi, nxt - off))
            off = nxt
        t += 3600
    return out


def fill(store, starts: list[float], seconds: float = 75.0) -> list[int]:
    ids = []
    for k, t0 in enumerate(starts):
        with store.begin_run("daily", rig="room1", started=t0) as h:
            for cam in ("cam1", "cam2"):
                h.measure(cam, "drift_x_px", round(0.11 * (k + 1), 3), "px")
                h.measure(cam, "drift_y_px", round(-0.07 * (k + 1), 3), "px")
                h.measure(cam, "drift_sd_px", 0.02, "px")
                h.measure(cam, "markers_missing", float(k % 2), "markers")
                h.measure(f"{cam}/M1", "drift_x_px", 0.1, "px")
            h.finish(finished=t0 + seconds)
            ids.append(h.run_id)
    return ids


def check_landed(site, store, run_ids):
    """Each run once in QATrack+, as the site shows it: times to the second, values, comment."""
    for rid in run_ids:
        run = store.run(rid)
        (tli,) = site.instances(run_key(run))
        shown_start = _dt.datetime.fromisoformat(tli["work_started"]).timestamp()
        shown_end = _dt.datetime.fromisoformat(tli["work_completed"]).timestamp()
        assert shown_start == math.floor(run.started), (tli["work_started"], run.started)
        # the end's second, at least the second after the start (QATrack+ moves an equal end 60 s on)
        end = math.floor(run.finished if run.finished is not None else run.started)
        assert shown_end == max(end, math.floor(run.started) + 1), (tli["work_completed"], run.finished)
        values = site.values(tli)
        for m in store.measurements(run_id=rid):
            macro = MACROS.get(f"{m.subject}/{m.metric}")
            if macro:
                assert values[macro]["value"] == pytest.approx(m.value) and not values[macro]["skipped"]
        assert values["cam3_dx"]["skipped"] and values["cam3_dx"]["value"] is None
        assert any(run_key(run) in c["comment"] and "room1" in c["comment"] for c in tli["comments"])


@pytest.mark.parametrize("zone", ["America/Toronto", "Australia/Sydney", "Europe/Berlin"])
def test_runs_land_at_their_true_instants_in_the_sites_zone_across_its_clock_changes(
    real_qatrack, tmp_path, monkeypatch, zone
):
    site = real_qatrack
    site.restart(zone)
    monkeypatch.setenv("QATRACK_TOKEN", site.tokens["QATRACK_TOKEN"])
    starts, repeated = [_dt.datetime(2026, 6, 15, 6, 5, 30, 700000, tzinfo=_dt.UTC).timestamp()], []
    for t, change in transitions(zone):
        if change > _dt.timedelta(0):  # clocks go forward: the hour skipped is never a run's time
            starts += [t - 45, t + 30]  # the run crosses the jump: its end an hour "later" on the wall
        else:  # clocks go back: the hour after t - |change| happens twice
            starts += [t - 2 * 3600, t + 3600 + 60]
            repeated += [t - 1800, t + 1200]
    with ResultsStore(tmp_path / "r.sqlite") as store:
        ids = fill(store, starts + repeated)
        ids += fill(store, [starts[0] + 86400 + 0.1], seconds=0.5)  # a run within one second
        out = push_runs(store, rig(site, zone), select_runs(store, rig(site, zone), "room1"))
        by_id = {o.run_id: o for o in out}
        landed = [i for i in ids if store.run(i).started not in repeated]
        assert [by_id[i].how for i in landed] == ["posted"] * len(landed), [by_id[i].line() for i in landed]
        check_landed(site, store, landed)
        for i in ids:
            if store.run(i).started in repeated:
                o = by_id[i]
                assert o.state == "refused" and o.how == "repeated hour" and "happens twice" in o.message
                assert "\n" not in o.message and site.instances(run_key(store.run(i))) == []
        assert exit_code(out) == 4  # a run refused: a person enters it by hand
    # the real site itself cannot take those wall-clock times: QATrack+ refuses them
    wall = _dt.datetime.fromtimestamp(repeated[0], ZoneInfo(zone)).strftime("%Y-%m-%d %H:%M:%S")
    r = requests.post(
        site.url + "api/qa/testlistinstances/",
        timeout=30,
        headers={"Authorization": f"Token {site.tokens['QATRACK_TOKEN']}"},
        json={
            "unit_test_collection": site.url + "api/qc/unittestcollections/1/",
            "work_started": wall,
            "work_completed": wall,
            "tests": {m: {"value": 0} for m in MACROS.values()},
        },
    )
    assert r.status_code == 400 and "Invalid datetime for the timezone" in r.text
    # and an end equal to the start is moved 60 s on (as the stand-in does: tests/integration/test_qatrack_push.py)
    wall = _dt.datetime.fromtimestamp(starts[0] + 2 * 86400, ZoneInfo(zone)).strftime("%Y-%m-%d %H:%M:%S")
    r = requests.post(
        site.url + "api/qa/testlistinstances/",
        timeout=30,
        headers={"Authorization": f"Token {site.tokens['QATRACK_TOKEN']}"},
        json={
            "unit_test_collection": site.url + "api/qc/unittestcollections/1/",
            "work_started": wall,
            "work_completed": wall,
            "tests": {m: {"value": 0} for m in MACROS.values()},
        },
    )
    assert r.status_code == 201, r.text
    made = r.json()
    assert _dt.datetime.fromisoformat(made["work_completed"]) - _dt.datetime.fromisoformat(
        made["work_started"]
    ) == _dt.timedelta(seconds=60)


def test_a_wrong_time_zone_in_rig_yaml_is_refused_before_anything_is_posted(real_qatrack, tmp_path, monkeypatch):
    site = real_qatrack
    site.restart("Australia/Sydney")
    monkeypatch.setenv("QATRACK_TOKEN", site.tokens["QATRACK_TOKEN"])
    with ResultsStore(tmp_path / "r.sqlite") as store:
        fill(store, [1.79e9])  # the site holds instances of earlier pushes: their times tell its zone
        qcfg = rig(site, "Europe/Berlin")
        out = push_runs(store, qcfg, select_runs(store, qcfg, "room1"))
        assert out[0].how == "wrong time zone" and exit_code(out) == 4
        assert "Europe/Berlin is not the site's TIME_ZONE" in out[0].message
        assert re.search(r"at UTC\+1[01]:00, where Europe/Berlin is at UTC\+0[12]:00", out[0].message), out[0].message
        assert site.instances(out[0].key) == [] and store.outbox_items("qatrack")[0].state == "pending"


def test_attachments_a_second_push_a_copy_of_the_store_and_a_server_stopped_mid_push(
    real_qatrack, tmp_path, monkeypatch
):
    site = real_qatrack
    site.restart("America/Toronto")
    monkeypatch.setenv("QATRACK_TOKEN", site.tokens["QATRACK_TOKEN"])
    db = tmp_path / "r.sqlite"
    with ResultsStore(db) as store:
        ids = fill(store, [1.7e9 + 86400 * d for d in range(5)])
    shutil.copy(db, tmp_path / "copy.sqlite")
    qcfg = rig(site, "America/Toronto", report="html", plots=True)

    def stop_after_two(n, total, outcome):
        if n == 2:
            site.stop()

    with ResultsStore(db) as store:
        out = push_runs(store, qcfg, select_runs(store, qcfg, "room1"), progress=stop_after_two)
        assert [o.state for o in out] == ["sent", "sent", "pending", "pending", "pending"]
        assert "not reachable" in out[2].message and exit_code(out) == 3
        site.restart("America/Toronto")
        again = push_runs(store, qcfg, select_runs(store, qcfg, "room1", pending=True))
        assert [o.how for o in again] == ["posted"] * 3 and exit_code(again) == 0
        check_landed(site, store, ids)
        tli = site.instances(run_key(store.run(ids[0])))[0]
        labels = sorted(a["label"] for a in tli["attachments"])
        assert labels == sorted(
            [f"vts-report-run{ids[0]}.html"] + [f"vts-drift-run{ids[0]}-{c}.png" for c in ("cam1", "cam2")]
        )
        second = push_runs(store, qcfg, select_runs(store, qcfg, "room1", run_ids=ids))
        assert [o.how for o in second] == ["already sent"] * 5
    with ResultsStore(tmp_path / "copy.sqlite") as copy:  # a copy taken before any push
        out = push_runs(copy, qcfg, select_runs(copy, qcfg, "room1"))
        assert [o.how for o in out] == ["already there"] * 5 and exit_code(out) == 0
    for rid in ids:
        with ResultsStore(db) as store:
            assert len(site.instances(run_key(store.run(rid)))) == 1


def test_vts_qa_daily_push_and_vts_qa_push_against_the_real_server(real_qatrack, sim_rig, tmp_path):
    """The commands the issue saw refused: `vts qa daily --push` on the simulated rig, and `vts qa
    push` (with its --dry-run) of a stored run, into the real QATrack+."""
    import yaml

    site = real_qatrack
    site.restart("America/Toronto")
    db = tmp_path / "r.sqlite"
    with ResultsStore(db) as store:
        (rid,) = fill(store, [1.76e9])
        key = run_key(store.run(rid))
    data = sim_rig.config().model_dump(mode="json", exclude_none=True)
    data.update(
        rig="room1",
        results={"url": f"sqlite:///{db}"},
        qatrack=qatrack_cfg(
            site,
            "America/Toronto",
            lists={"daily": {"test_list": LIST, "macros": dict(MACROS), "ignore": ["*/M*/*", "cam?/*"]}},
        ),
    )
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(yaml.safe_dump(data))
    token = site.tokens["QATRACK_TOKEN"]
    env = {**os.environ, **sim_rig.env_vars(), "VTS_CONFIG": str(cfg), "QATRACK_TOKEN": token}

    def vts(*a):
        p = subprocess.run(VTS + list(a), env=env, capture_output=True, text=True, timeout=300)
        assert token not in p.stdout + p.stderr and "Traceback" not in p.stderr
        return p

    dry = vts("qa", "push", "--dry-run", str(rid))
    # 1.76e9 is 2025-10-09 08:53:20 UTC: 04:53:20 on the site's clock (EDT)
    assert dry.returncode == 0 and "2025-10-09 04:53:20" in dry.stdout and "America/Toronto" in dry.stdout, dry.stderr
    p = vts("qa", "push", "--json", str(rid))
    assert p.returncode == 0 and [o["how"] for o in json.loads(p.stdout)["outcomes"]] == ["posted"], p.stderr
    (tli,) = site.instances(key)
    assert tli["work_started"] == "2025-10-09T04:53:20-04:00"
    assert vts("qa", "drift", "--set-baseline", "--frames", "2").returncode == 0
    p = vts("qa", "daily", "--frames", "2", "--push")
    assert p.returncode == 0 and "posted in QATrack+" in p.stderr, p.stdout + p.stderr
    with ResultsStore(db) as store:
        daily = store.runs(procedure="daily")[-1]
        check_landed(site, store, [daily.id])
