"""The Room page finished (issue 23 §1): the LED as the camera says it, markers named, in a real
headless Chromium (Debian's) against the simulated cameras over HTTP and a real SQLite store.

* The LED is read back from the camera, not assumed: switched behind the console's back (as the
  daily QA does), the page follows within seconds; a switch the camera does not take (its
  ``led_held`` fault: an action rule holding the output) is said on the page, and the state
  shown is the one the camera reports; a camera off the network has its LED "not known".
* Markers named, not numbered: each of cam1's detections that lies within the drift QA's gate of
  a marker of its drift baseline in the store carries that marker's name (M1..) and the wall's
  colour; one the baseline does not hold is "unidentified" and numbered; the names the Scan page
  gives (the live tracker's band markers) name theirs; the legend says what named them.
"""

from __future__ import annotations

import numpy as np
import pytest

from console_live import cam, served_room, until
from vts_hw.console.names import MarkerNames
from vts_hw.drivers.registry import open_camera
from vts_hw.procedures.baseline import BaselineSet, take_baseline
from vts_hw.sim_devices.rig import SimRig
from vts_hw.store import ResultsStore
from vts_hw.store.recorder import record
from vts_hw.vision.marker_roles import GATE_PX
from vts_hw.vision.wall_baseline import Baseline

pytestmark = pytest.mark.timeout(180)


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    db = tmp_path_factory.mktemp("room") / "results.sqlite"
    with SimRig(n_cameras=2, seed=5) as rig, rig.env():
        cams = {c.name: open_camera(c) for c in rig.config().cameras}
        # cam1's drift baseline without its last marker (that one stays unidentified); the LED is left on
        full = take_baseline(cams["cam1"], frames=2)
        kept = Baseline("cam1", full.markers[:-1], full.taken)
        with ResultsStore(db) as store:
            record(store, BaselineSet([kept]), rig="sim", operator="test")
            # another room's cam1, set later: not this room's camera, never its names
            record(store, BaselineSet([Baseline("cam1", (), full.taken)]), rig="elsewhere", operator="test")
        with served_room(rig, cams, db) as lc:
            lc.full, lc.kept = full, kept
            yield lc


@pytest.fixture()
def page(browser, live):
    pg = browser.new_page(viewport={"width": 1366, "height": 768})
    pg.goto(live.url)
    yield pg
    pg.close()


def test_the_led_is_what_the_camera_says_and_a_switch_that_did_not_take_is_said(live, page):
    src, server = live.rig.sources["cam2"], live.rig.servers["cam2"]
    src.set_led(False)
    assert until(lambda: cam(page, "cam2", "e => e.dataset.led") == "off", 20)
    assert "OFF (read from the camera" in cam(page, "cam2", "e => e.querySelector('.led').textContent")
    src.set_led(True)  # behind the console's back (the daily QA switches it so)
    assert until(lambda: cam(page, "cam2", "e => e.dataset.led") == "on", 20)
    # the switch: off, read back at once
    page.click('section[data-camera="cam2"] button.led-off')
    assert until(lambda: cam(page, "cam2", "e => [e.dataset.led, e.dataset.ledTook]") == ["off", "yes"], 10)
    assert not src.led_on()
    # a rule on the camera holds the output: the camera answers OK and its LED stays off
    server.faults.led_held = True
    try:
        page.click('section[data-camera="cam2"] button.led-on')
        assert until(lambda: cam(page, "cam2", "e => e.dataset.ledTook") == "no", 10)
        said = cam(page, "cam2", "e => [e.dataset.led, e.querySelector('.led-error').textContent]")
        assert said[0] == "off" and not src.led_on()
        assert "switched on here, but the camera says its LED output is off: the switch did not take" in said[1]
        did = live.console.actions.recent(1)[0]
        assert (did.what, did.detail) == ("LED on", {"camera": "cam2", "took": False, "read back": "off"})
    finally:
        server.faults.led_held = False
    page.click('section[data-camera="cam2"] button.led-on')
    assert until(lambda: cam(page, "cam2", "e => [e.dataset.led, e.dataset.ledTook]") == ["on", "yes"], 10)
    assert cam(page, "cam2", "e => e.querySelector('.led-error').textContent") == ""
    # a camera that does not answer: its LED is not known (never its last state), and why
    server.faults.offline = True
    try:
        assert until(lambda: cam(page, "cam2", "e => e.dataset.led") == "unknown", 20)
        said = cam(page, "cam2", "e => e.querySelector('.led').textContent")
        assert (
            said.startswith("not known: the camera did not say (camera cam2 at http://127.0.0.1:")
            and "password" not in said
        ), said
    finally:
        server.faults.offline = False
    assert until(lambda: cam(page, "cam2", "e => e.dataset.led") == "on", 20)


def test_times_are_iso_and_utc_whatever_the_browsers_locale_and_zone(browser, live):
    """The pages say times as every file and report does (ISO 8601, UTC), not in the browser's
    locale and zone: opened as a browser in New York with the en-US locale (11/29/2026, 9:03 AM)."""
    import datetime
    import re

    ctx = browser.new_context(locale="en-US", timezone_id="America/New_York")
    try:
        pg = ctx.new_page()
        pg.goto(live.url)
        assert until(lambda: re.fullmatch(r"\d\d:\d\d:\d\d UTC", pg.inner_text("#clock") or ""), 10), pg.inner_text(
            "#clock"
        )
        shown = datetime.datetime.strptime(pg.inner_text("#clock")[:8], "%H:%M:%S").time()
        now = datetime.datetime.now(datetime.UTC)
        gap = (
            abs(
                (now.hour * 3600 + now.minute * 60 + now.second)
                - (shown.hour * 3600 + shown.minute * 60 + shown.second)
            )
            % 86400
        )
        assert min(gap, 86400 - gap) < 120, (shown, now)  # UTC, not New York's hour
        assert pg.evaluate("window.vtsClock.stamp(1764406987)") == "2025-11-29 09:03:07 UTC"
    finally:
        ctx.close()


def circles(page, name):
    return cam(
        page,
        name,
        """e => [...e.querySelectorAll('svg circle')].map(c => {
        const t = c.nextElementSibling;
        return {x: +c.dataset.x, y: +c.dataset.y, kind: c.dataset.kind, label: t.textContent,
                cls: c.getAttribute('class')}; })""",
    )


def test_markers_are_named_wall_from_the_baseline_band_from_the_scan_unidentified_otherwise(live, page):
    base = {m.id: (m.x, m.y) for m in live.kept.markers}
    left_out = live.full.markers[-1]
    assert len(base) >= 3

    def named():
        got = circles(page, "cam1")
        return got if sum(c["kind"] == "wall" for c in got) == len(base) else None

    got = until(named, 30)
    assert got, circles(page, "cam1")
    for c in got:
        if c["kind"] == "wall":
            x, y = base[c["label"]]
            assert np.hypot(c["x"] - x, c["y"] - y) <= GATE_PX and c["cls"] == "k-wall"
    stray = [c for c in got if c["kind"] == "unidentified"]
    assert len(stray) == 1 and np.hypot(stray[0]["x"] - left_out.x, stray[0]["y"] - left_out.y) < 2
    assert stray[0]["label"].startswith("? ")
    legend = cam(page, "cam1", "e => [...e.querySelectorAll('.legend li')].map(l => [l.dataset.kind, l.textContent])")
    assert legend[0][0] == "wall" and f"{len(base)} of {len(base)} named here, from drift baseline run" in legend[0][1]
    assert legend[-1][0] == "unidentified"
    assert f"{len(base)} wall markers, 1 unidentified" in cam(
        page, "cam1", "e => e.querySelector('.marks').textContent"
    )
    # cam2 has no baseline (nor another room's): nothing named, and the legend says why
    assert until(lambda: circles(page, "cam2"), 30)
    assert {c["kind"] for c in circles(page, "cam2")} == {"unidentified"}
    assert "no names known" in cam(page, "cam2", "e => e.querySelector('.legend').textContent") or cam(
        page, "cam2", "e => [...e.querySelectorAll('.legend li')].map(l => l.dataset.kind)"
    ) == ["unidentified"]
    # the Scan page names the band markers the live tracker follows (the hook: per camera, in pixels)
    live.console.names.set(
        "cam1",
        "band",
        [("chest 1", stray[0]["x"] + 3.0, stray[0]["y"] - 2.0)],
        source="the live tracker (scan 7)",
        hold_s=60,
    )
    assert until(lambda: [c["label"] for c in circles(page, "cam1") if c["kind"] == "band"] == ["chest 1"], 10)
    legend = cam(page, "cam1", "e => [...e.querySelectorAll('.legend li')].map(l => [l.dataset.kind, l.textContent])")
    assert legend[0][0] == "band" and "1 of 1 named here, from the live tracker (scan 7)" in legend[0][1]
    assert "unidentified" not in [k for k, _ in legend]
    live.console.names.clear("cam1", "band")
    assert until(lambda: [c["kind"] for c in circles(page, "cam1")].count("unidentified") == 1, 10)


def test_names_are_matched_one_to_one_within_the_gate_and_expire():
    t = [1000.0]
    names = MarkerNames(clock=lambda: t[0])
    marks = [{"n": 1, "x": 100.0, "y": 100.0}, {"n": 2, "x": 108.0, "y": 100.0}, {"n": 3, "x": 300.0, "y": 50.0}]
    names.set("cam1", "wall", [("M1", 101.0, 100.0), ("M2", 300.0, 50.0 + GATE_PX + 0.5)], source="baseline")
    names.set("cam1", "band", [("B1", 104.0, 100.0)], source="tracker", hold_s=1.0)
    out, legend = names.label("cam1", marks)
    # the band marker first (nearest of the two to B1: n=1 at 4 px, n=2 at 4 px -> one of them, once),
    # then the wall gets the other within its gate; M2 is 12.5 px off: too far, n=3 unidentified
    kinds = {m["n"]: (m["kind"], m["name"]) for m in out}
    assert sorted(v for v in kinds.values() if v[0] != "unidentified") == [("band", "B1"), ("wall", "M1")]
    assert kinds[3] == ("unidentified", "3")
    assert [(entry["kind"], entry["found"], entry["known"]) for entry in legend] == [("band", 1, 1), ("wall", 1, 2)]
    t[0] += 1.5  # the band's names held 1 s
    out, legend = names.label("cam1", marks)
    assert [entry["kind"] for entry in legend] == ["wall"] and sum(m["kind"] == "wall" for m in out) == 1
    assert names.label("cam2", marks)[1] == []
    with pytest.raises(ValueError, match="marker kind must be one of"):
        names.set("cam1", "ceiling", [], source="x")
