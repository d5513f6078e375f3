"""A department's view: runs of three rooms in one store (tests/rooms_store.py), the rooms page
(`vts report rooms`), the drift report for one rig or all of them (`--rig`), the history of the
sync checks, mappings, calibrations and motion analyses, and the rooms page in a real browser."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path
from urllib.parse import urljoin

import pytest

from inprocess_cli import vts
from rooms_store import DAY, NOW, RIGS, T0, rooms_store
from vts_hw.report.build import build_rooms_report
from vts_hw.report.drift import collect
from vts_hw.report.rooms import collect_rooms, open_items
from vts_hw.store import ResultsStore


@pytest.fixture(scope="module")
def store_url(tmp_path_factory) -> str:
    return rooms_store(tmp_path_factory.mktemp("rooms") / "dept.sqlite")


@pytest.fixture(scope="module")
def rooms_page(store_url, tmp_path_factory):
    out = tmp_path_factory.mktemp("page") / "rooms.html"
    with ResultsStore(store_url) as store:
        rep = build_rooms_report(store, out, since=NOW - 60 * DAY, now=NOW)
    return rep, out


def _room(rep, rig):
    return next(r for r in rep.rooms if r.rig == rig)


def rig_yaml(folder: Path, url: str, rig: str = "room-a") -> Path:
    cfg = folder / "rig.yaml"
    cfg.write_text(f"rig: {rig}\ncameras:\n  - name: cam1\n    host: 127.0.0.1\nstore:\n  url: {url}\n")
    return cfg


# --- the store and the rules ---------------------------------------------------------------


def test_runs_carry_their_rig(store_url):
    with ResultsStore(store_url) as store:
        assert store.rigs() == list(RIGS)
        assert {r.rig for r in store.runs(procedure="calibration_cameras")} == {"room-c"}


def test_open_action_items_follow_the_rule(rooms_page):
    rep, _ = rooms_page
    b = _room(rep, "room-b")
    items = {(i.check, i.subject): i for i in b.open_items}
    # cam2's drift ACTION on the last 3 days is open; cam1's LED ACTION on day 6 was closed by later OK runs
    assert set(items) == {("daily QA", "cam2"), ("step test", "x")}
    cam2 = items[("daily QA", "cam2")]
    assert cam2.metrics == ["drift_y_px"] and cam2.runs == 3 and cam2.since == T0 + 17 * DAY + 7 * 3600
    assert items[("step test", "x")].metrics == ["steps_diff_max_mm"]
    # room-a: a motion analysis ACTION (a patient's scan) and a sync check in TOLERANCE are no open item
    assert _room(rep, "room-a").open_items == []


def test_open_item_closed_by_a_later_ok_of_the_same_check(store_url):
    with ResultsStore(store_url) as store:
        runs = [r for r in store.runs() if r.rig == "room-b"]
        meas = store.measurements()
    day6 = [r for r in runs if r.procedure == "daily" and r.started < T0 + 7 * DAY]
    items = open_items(meas, day6)  # history up to day 6: the LED ACTION is still open
    assert [(i.subject, i.metrics) for i in items] == [("cam1", ["led_off_visible"])]


def test_room_states_and_never_ok_without_data(rooms_page, store_url):
    rep, out = rooms_page
    a, b, c = (_room(rep, r) for r in RIGS)
    # a room is the worst of its latest results, whatever the check: room-a's cameras are OK, but
    # its latest sync check is TOLERANCE; room-c has no daily QA and nothing worse than OK: no state
    assert str(a.state) == "TOLERANCE" and str(b.state) == "ACTION" and c.state is None
    assert {n: str(cam.state) for n, cam in a.drift.cameras.items()} == {"cam1": "OK", "cam2": "OK"}
    assert c.daily_missing_text() == "no daily QA yet"
    assert {n: str(cam.state) for n, cam in b.drift.cameras.items()} == {"cam1": "OK", "cam2": "ACTION"}
    html = out.read_text()
    row_c = re.search(r'<tr class="room" data-rig="room-c" data-state="(\w+)">(.*?)</tr>', html, re.S)
    assert row_c and row_c.group(1) == "none" and "no daily QA yet" in row_c.group(2)
    assert ">OK<" not in row_c.group(2).split("<td", 3)[2]  # the cameras cell says no state at all
    with ResultsStore(store_url) as store:  # runs before the period: said so, not OK
        late = collect_rooms(store, since=NOW - 0.5 * DAY, now=NOW, rigs=["room-a"])
    assert str(late.rooms[0].state) == "TOLERANCE" and not late.rooms[0].has_daily  # the sync check, never OK
    assert late.rooms[0].daily_missing_text() == "no daily QA in the period (last 2026-10-20)"


def test_days_since_the_last_step_test_and_calibration(rooms_page):
    rep, out = rooms_page
    a = _room(rep, "room-a")
    assert a.last_steps.started == T0 + 5 * DAY + 9 * 3600 and a.last_calibration.procedure == "calibration"
    assert _room(rep, "room-b").last_calibration is None
    html = out.read_text()
    row_a = re.search(r'<tr class="room" data-rig="room-a".*?</tr>', html, re.S).group(0)
    assert "14 days ago" in row_a and "17 days ago" in row_a  # step test day 5, calibration day 2
    row_b = re.search(r'<tr class="room" data-rig="room-b".*?</tr>', html, re.S).group(0)
    assert "no calibration recorded" in row_b and "ACTION since 2026-10-18" in row_b


def test_page_is_self_contained_with_sparklines_and_relative_links(rooms_page):
    rep, out = rooms_page
    html = out.read_text()
    assert not re.search(r'(src|href)="(https?:)?//', html) and "@import" not in html
    assert html.count('<svg class="spark"') == 4  # cam1 and cam2 of room-a and room-b
    links = re.findall(r'<a class="drift-link" href="([^"]+)"', html)
    assert links == [f"rooms-{r}-drift.html" for r in RIGS]
    for link in links:
        drift = (out.parent / link).read_text()
        assert drift.startswith("<!DOCTYPE html>")
    assert "VTS camera drift — room-b" in (out.parent / links[1]).read_text()
    assert "An ACTION item is open while the latest completed result" in html


# --- the history of the other QA runs in the drift report --------------------------------------


def test_drift_report_has_the_history_and_lists_the_sync_check(store_url):
    with ResultsStore(store_url) as store:
        rep = collect(store, since=None, now=NOW, rig="room-a")
        other = collect(store, since=None, now=NOW, rig="room-c")
    keys = [h.spec.key for h in rep.history]
    assert keys == ["sync", "spect_mapping", "calibration", "motion"]
    sync = rep.history[0]
    assert [r.values[0][0] for r in sync.shown] == [35.0, 12.0, 8.0]  # newest first
    assert sync.latest.status == "TOLERANCE"
    att = rep.attention()
    assert any(a.startswith("sync check (room-a): TOLERANCE in run") and "sync_max_abs_dt_ms" in a for a in att)
    assert not any("motion" in a for a in att)  # a patient who moved is not the room's fault
    assert rep.plot_count == 2 + 2  # two cameras; the sync and motion trends
    assert [h.spec.key for h in other.history] == ["calibration"] and other.attention()[-1].startswith("no drift")
    assert other.history[0].shown[0].values[:2] == [(0.4, "OK"), (0.35, "OK")]  # the set; the worst camera


# --- the commands ------------------------------------------------------------------------------


def test_report_drift_rig_all_keeps_rooms_apart(store_url, tmp_path, capsys):
    cfg = rig_yaml(tmp_path, store_url)
    code, out, err = vts(
        capsys, "report", "drift", "--config", cfg, "--rig", "all", "--since", "all", "-o", tmp_path / "all.html"
    )
    assert code == 0, err
    assert out.strip() == f"wrote {tmp_path / 'all.html'} (3 rig(s))"
    html = (tmp_path / "all.html").read_text()
    for i, rig in enumerate(RIGS):
        assert f'id="room-{i}"' in html and f"VTS camera drift — {rig}" in html
    assert 'id="room-0-cam-cam1"' in html and 'id="room-1-cam-cam1"' in html  # cam1 of each room apart
    code, out, _ = vts(
        capsys,
        "report",
        "drift",
        "--config",
        cfg,
        "--rig",
        "room-b",
        "--since",
        "all",
        "--json",
        "-o",
        tmp_path / "b.html",
    )
    import json

    data = json.loads(out)
    assert code == 0 and data["rig"] == "room-b" and data["cameras"]["cam2"]["state"] == "ACTION"


def test_report_commands_refuse_bad_options(store_url, tmp_path, capsys):
    cfg = rig_yaml(tmp_path, store_url)
    code, out, err = vts(capsys, "report", "drift", "--config", cfg, "--rig", "room-z", "-o", tmp_path / "z.html")
    assert code == 2 and err.count("\n") == 1 and "--rig 'room-z': the store has no runs of that rig" in err
    code, _, err = vts(capsys, "report", "rooms", "--config", cfg, "-o", tmp_path / "rooms.txt")
    assert code == 2 and "is written as .html or .pdf" in err
    code, _, err = vts(capsys, "report", "rooms", "--config", cfg, "--since", "9999-12-31", "-o", tmp_path / "r.html")
    assert code == 2 and "is in the future" in err
    assert not list(tmp_path.glob("*.html"))


def test_a_department_workstation_needs_no_rig_config(store_url, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no ./rig.yaml here
    monkeypatch.delenv("VTS_CONFIG", raising=False)
    code, out, err = vts(capsys, "--store", store_url, "report", "rooms", "--since", "all", "-o", "rooms.html")
    assert code == 0, err
    assert "(3 room(s)" in out and (tmp_path / "rooms-room-b-drift.html").exists()
    code, _, err = vts(capsys, "--store", store_url, "report", "drift", "-o", "d.html")
    assert code == 2 and err.count("\n") == 1 and "give --rig NAME or --rig all" in err
    monkeypatch.setenv("VTS_STORE", store_url)
    code, out, err = vts(capsys, "report", "drift", "--rig", "room-b", "--since", "all", "-o", "d.html")
    assert code == 0 and out.strip() == "wrote d.html", err


def test_report_rooms_pdf_and_a_folder_that_cannot_be_written(store_url, tmp_path, capsys, readonly_dir):
    cfg = rig_yaml(tmp_path, store_url)
    code, out, err = vts(
        capsys, "report", "rooms", "--config", cfg, "--since", "all", "--rig", "room-b", "-o", tmp_path / "rooms.pdf"
    )
    assert code == 0, err
    assert out.strip() == f"wrote {tmp_path / 'rooms.pdf'} (1 room(s))"
    assert err.strip() == f"wrote {tmp_path / 'rooms-room-b-drift.pdf'} (room-b)"  # progress
    for name in ("rooms.pdf", "rooms-room-b-drift.pdf"):
        assert (tmp_path / name).read_bytes()[:5] == b"%PDF-"
    text = subprocess.run(
        ["pdftotext", "-layout", str(tmp_path / "rooms.pdf"), "-"], capture_output=True, text=True
    ).stdout
    assert "Department ACTION" in text and "ACTION since 2026-10-18" in text and "rooms-room-b-drift.pdf" in text
    assert "An ACTION item is open while the latest" in " ".join(text.split())
    code, _, err = vts(capsys, "report", "rooms", "--config", cfg, "-o", readonly_dir / "rooms.html")
    assert code == 3 and err.startswith("vts: ") and err.count("\n") == 1
    assert not list(readonly_dir.iterdir())


def test_an_empty_store_says_so_in_every_form(tmp_path, capsys):
    cfg = rig_yaml(tmp_path, f"sqlite:///{tmp_path / 'empty.sqlite'}")
    ResultsStore(tmp_path / "empty.sqlite").close()  # a store without runs (reports make none)
    for args in (("rooms", "-o", tmp_path / "rooms.html"), ("drift", "--rig", "all", "-o", tmp_path / "all.pdf")):
        code, out, err = vts(capsys, "report", *args, "--config", cfg)
        assert code == 0, err
    html = (tmp_path / "rooms.html").read_text()
    assert "The store holds no runs yet." in html and 'data-state="none"' in html and "badge OK" not in html
    text = subprocess.run(["pdftotext", str(tmp_path / "all.pdf"), "-"], capture_output=True, text=True).stdout
    assert "the store holds no runs yet" in text


# --- in a real browser -------------------------------------------------------------------------


def test_rooms_page_in_chromium_and_a_link_followed(rooms_page, tmp_path):
    from test_report import _run_chromium

    _, out = rooms_page
    r = _run_chromium(tmp_path, "--virtual-time-budget=3000", "--dump-dom", out.resolve().as_uri())
    assert r.returncode == 0, r.stderr[-2000:]
    rows = re.findall(r'<tr class="room" data-rig="([^"]*)" data-state="([^"]*)"', r.stdout)
    assert rows == [("room-a", "TOLERANCE"), ("room-b", "ACTION"), ("room-c", "none")]
    assert len(re.findall(r'<svg class="spark"', r.stdout)) == 4
    href = re.search(r'<tr class="room" data-rig="room-b".*?<a class="drift-link" href="([^"]+)"', r.stdout, re.S)
    target = urljoin(out.resolve().as_uri(), href.group(1))  # where the browser goes on a click
    r = _run_chromium(tmp_path, "--virtual-time-budget=5000", "--dump-dom", target)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "<title>VTS camera drift — room-b</title>" in r.stdout
    m = re.search(
        r'<body[^>]*data-plots-expected="(\d+)"[^>]*data-state="ACTION"[^>]*data-plots-loaded="(\d+)"', r.stdout
    )
    assert m and m.group(1) == m.group(2) and int(m.group(1)) >= 2, r.stdout[:600]
