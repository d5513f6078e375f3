"""A camera that did not answer the daily QA is never shown OK: the rooms page and the drift
report (issue 21, part A 1), on the simulated rig with cam2 offline, through the real commands."""

from __future__ import annotations

import json
import re

import pytest
import yaml

from inprocess_cli import vts


@pytest.fixture()
def offline_day(sim_rig, tmp_path, capsys, monkeypatch):
    """A baseline, one good daily QA, then a daily QA with cam2 off the network (ACTION)."""
    data = sim_rig.config(rig_name="room-1").model_dump(mode="json", exclude_none=True)
    data["store"] = {"url": f"sqlite:///{tmp_path / 'results.sqlite'}"}
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(yaml.safe_dump(data))
    monkeypatch.setenv("VTS_CONFIG", str(cfg))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    code, out, err = vts(capsys, "qa", "drift", "--set-baseline", "--frames", "2")
    assert code == 0, err
    code, out, err = vts(capsys, "qa", "daily", "--frames", "2")
    assert code == 0, out + err
    sim_rig.servers["cam2"].faults.offline = True
    code, out, err = vts(capsys, "qa", "daily", "--frames", "2", "--json")
    assert code == 20, out + err
    cams = {c["camera"]: c for c in json.loads(out)["cameras"]}
    assert cams["cam2"]["state"] == "ACTION" and cams["cam1"]["state"] == "OK"
    reach = [m for m in cams["cam2"]["measurements"] if m["metric"] == "camera_reachable"]
    assert reach and reach[-1]["value"] == 0
    return tmp_path


def test_an_unreachable_camera_is_action_in_both_reports_until_it_answers(offline_day, sim_rig, capsys):
    _rooms_page_shows_the_unreachable_camera_as_action(offline_day, capsys)
    _drift_report_overall_is_action_and_says_why(offline_day, capsys)
    _a_later_good_daily_qa_makes_the_camera_ok_again(offline_day, sim_rig, capsys)


def _rooms_page_shows_the_unreachable_camera_as_action(offline_day, capsys):
    out = offline_day / "rooms.html"
    code, text, err = vts(capsys, "report", "rooms", "-o", out, "--json")
    assert code == 0, err
    rep = json.loads(text)
    room = next(r for r in rep["rooms"] if r["rig"] == "room-1")
    assert rep["state"] == "ACTION" and room["state"] == "ACTION"
    assert room["cameras"]["cam2"]["state"] == "ACTION"
    assert room["cameras"]["cam1"]["state"] == "OK"
    html = out.read_text()
    assert re.search(r'data-camera="cam2" data-state="ACTION"', html)
    banner = re.search(r"Department\s*<span class=\"badge (\w+)\"", html)
    assert banner and banner.group(1) == "ACTION"
    assert 'data-rig="room-1" data-state="ACTION"' in html
    # the open items column says the same
    assert any(i["subject"] == "cam2" and "camera_reachable" in i["metrics"] for i in room["open_items"])


def _drift_report_overall_is_action_and_says_why(offline_day, capsys):
    out = offline_day / "drift.html"
    code, text, err = vts(capsys, "report", "drift", "-o", out, "--json")
    assert code == 0, err
    rep = json.loads(text)
    assert rep["state"] == "ACTION"
    cam2 = rep["cameras"]["cam2"]
    assert cam2["state"] == "ACTION"
    assert cam2["latest"]["values"].get("drift_x_px") is None  # the drift of that run is not known
    assert any(a.startswith("cam2: ACTION") and "camera_reachable" in a for a in rep["attention"])
    html = out.read_text()
    overall = re.search(r"Overall\s*<span class=\"badge (\w+)\"", html)
    assert overall and overall.group(1) == "ACTION"
    assert "not measured" in html


def _a_later_good_daily_qa_makes_the_camera_ok_again(offline_day, sim_rig, capsys):
    sim_rig.servers["cam2"].faults.offline = False
    code, out, err = vts(capsys, "qa", "daily", "--frames", "2")
    assert code == 0, out + err
    code, text, err = vts(capsys, "report", "rooms", "-o", offline_day / "rooms.html", "--json")
    room = json.loads(text)["rooms"][0]
    assert room["state"] == "OK" and room["cameras"]["cam2"]["state"] == "OK" and room["open_items"] == []
