"""Aim and focus live on the console's Room page (issue 24 §2), in a real headless Chromium
(Debian's) against two simulated Axis cameras over HTTP, their drift baselines in a real SQLite
store and the rig's true calibration and mapping in its config.

* Switched on for a camera, the page shows each item's verdict in colour and in words and the
  check's picture in place of the live one; the lens put out of focus, then the mount turned
  (the simulator's POST /sim/optics), the verdicts turn to ADJUST with what to do; set back,
  GOOD again.
* The check takes its pictures from the console's own frames, switching the LED for the other
  one and back: the LED is as it was found (off, or on), and the LED-off item was measured.
* While a recording feeds the hub (``hub.attach``: a scan, the daily QA), switching it on is
  refused in one sentence, and a camera already on says it is not checked (the LED untouched);
  the checks go on when the recording is done.
"""

from __future__ import annotations

import json

import pytest
import requests

from console_live import cam, served_room, until
from vts_hw.drivers.registry import open_camera
from vts_hw.procedures.baseline import take_baselines
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.sync_truth import write_true_calibration
from vts_hw.store import ResultsStore
from vts_hw.store.recorder import record

pytestmark = pytest.mark.timeout(240)


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    folder = tmp_path_factory.mktemp("aim")
    db = folder / "results.sqlite"
    with SimRig(n_cameras=2, seed=5) as rig, rig.env():
        cal, mp = write_true_calibration(rig.scene, folder)
        mapped = rig.config(calibration={"stereo": str(cal), "spect": str(mp)})
        cams = {c.name: open_camera(c) for c in mapped.cameras}
        with ResultsStore(db) as store:  # each camera's wall markers: the aim's reference (LED left on)
            record(store, take_baselines(list(cams.values()), frames=2), rig="sim", operator="test")
        with served_room(rig, cams, db, rig_config=mapped) as lc:
            yield lc


@pytest.fixture()
def page(browser, live):
    pg = browser.new_page(viewport={"width": 1366, "height": 768})
    pg.goto(live.url)
    yield pg
    for name in live.console.hub.names:  # every test leaves the checks off (and ended)
        live.console.aim.switch(name, False)
        until(lambda name=name: not live.console.aim.view(name)["busy"], 30)
    pg.close()


def optics(live, name, **changes):
    r = requests.post(
        f"http://127.0.0.1:{live.rig.servers[name].port}/sim/optics", data=json.dumps(changes), timeout=10
    )
    assert r.status_code == 200, r.text


def verdicts(page, name):
    """{item: (state, the words shown, its colour)} as the page shows them, and the check's number."""
    got = cam(
        page,
        name,
        """e => [+(e.dataset.aimCheck || 0), [...e.querySelectorAll('.aim-items li')].map(li =>
        [li.dataset.item, li.dataset.state, li.textContent, getComputedStyle(li).borderLeftColor])]""",
    )
    return got[0], {item: (state, text, colour) for item, state, text, colour in got[1]}


def after_a_new_check(page, name, test, timeout=60):
    """The verdicts of a check made after now that pass ``test`` (their dict), or None."""
    n0 = verdicts(page, name)[0]
    return until(lambda: (lambda n, v: v if n > n0 and test(v) else None)(*verdicts(page, name)), timeout, poll=0.3)


def why(live, name):
    """What the check of ``name`` is doing, and where its thread is (for a failure's message)."""
    import sys
    import traceback

    view = {k: v for k, v in live.console.aim.view(name).items() if k != "verdicts"}
    t = live.console.aim._thread
    frame = sys._current_frames().get(t.ident) if t is not None else None
    return view, "".join(traceback.format_stack(frame)[-4:]) if frame is not None else "no thread"


def checks_done(live, name):
    return live.console.aim.view(name)["n"]


def click_aim(page, live, name, on: bool):
    """Click the switch and wait until the console has it (the click's POST is asynchronous)."""
    page.click(f'section[data-camera="{name}"] button.aim-{"on" if on else "off"}')
    assert until(lambda: live.console.aim.view(name)["on"] == on, 10), why(live, name)


def wait_idle(live, name):
    """The check switched off has ended (a check under way finishes, LED put back)."""
    assert until(lambda: not live.console.aim.view(name)["busy"], 30)


def test_verdicts_show_and_turn_to_adjust_when_defocused_and_turned(live, page):
    click_aim(page, live, "cam1", True)
    got = after_a_new_check(page, "cam1", lambda v: len(v) >= 7, 60)
    assert got, verdicts(page, "cam1")
    assert {item: state for item, (state, _, _) in got.items()} == {
        "focus": "good",
        "size": "good",
        "contrast": "good",
        "background": "good",
        "led_off": "good",
        "aim": "good",
        "fov": "good",
        "gantry": "good",
    }, got
    assert all(text.startswith("GOOD") for _, text, _ in got.values())
    assert cam(page, "cam1", "e => [e.dataset.aim, e.querySelector('.aim-word').textContent]")[0] == "good"
    # the check's picture in place of the live one (a PNG the console drew: markers, FOV, table, gantry)
    assert until(lambda: cam(page, "cam1", "e => e.querySelector('img.aim-picture').naturalWidth") == 640, 20)
    assert cam(
        page,
        "cam1",
        "e => [getComputedStyle(e.querySelector('.frame')).display, "
        "getComputedStyle(e.querySelector('.aim-view')).display]",
    ) == ["none", "grid"]
    # cam2 not switched on: its live picture, no check
    assert cam(page, "cam2", "e => [e.dataset.aim, getComputedStyle(e.querySelector('.frame')).display]") == [
        "off",
        "block",
    ]
    assert checks_done(live, "cam2") == 0
    good_colour = got["focus"][2]

    optics(live, "cam1", focus_blur_px=1.5)  # the lens put out of focus
    blurred = after_a_new_check(page, "cam1", lambda v: v.get("focus", ("",))[0] == "adjust")
    assert blurred, verdicts(page, "cam1")
    state, text, colour = blurred["focus"]
    assert text.startswith("ADJUST focus: turn the focus ring: the markers' edges are") and colour != good_colour
    assert blurred["aim"][0] == "good"
    assert cam(page, "cam1", "e => e.dataset.aim") == "adjust"
    assert cam(page, "cam1", "e => e.querySelector('.aim-word').textContent").startswith("ADJUST")

    optics(live, "cam1", focus_blur_px=0.0, yaw_deg=3.0)  # in focus, the mount turned 3° to the right
    turned = after_a_new_check(page, "cam1", lambda v: v.get("aim", ("",))[0] == "adjust" and v["focus"][0] == "good")
    assert turned, verdicts(page, "cam1")
    assert "aim: aim 3.0° left" in turned["aim"][1], turned["aim"]

    optics(live, "cam1", yaw_deg=0.0)  # set back
    back = after_a_new_check(page, "cam1", lambda v: all(s == "good" for s, _, _ in v.values()))
    assert back, verdicts(page, "cam1")
    did = [a for a in live.console.actions.recent(5) if a.what.startswith("aim check")]
    assert did and (did[0].what, did[0].detail) == ("aim check on", {"camera": "cam1"})


@pytest.mark.parametrize("led_before", [False, True])
def test_the_led_is_left_as_it_was_found(live, page, led_before):
    src = live.rig.sources["cam2"]
    src.set_led(led_before)
    word = "on" if led_before else "off"
    assert until(lambda: cam(page, "cam2", "e => e.dataset.led") == word, 20)
    n0 = checks_done(live, "cam2")
    click_aim(page, live, "cam2", True)
    assert until(lambda: checks_done(live, "cam2") >= n0 + 1, 60), why(live, "cam2")
    click_aim(page, live, "cam2", False)
    wait_idle(live, "cam2")
    view = live.console.aim.view("cam2")
    assert src.led_on() == led_before and view["led_found"] == word
    items = {i["item"]: i for i in view["verdicts"]["items"]}
    # both pictures were taken: the markers shine with the LED on, and keep little of it off
    assert items["contrast"]["state"] == items["led_off"]["state"] == "good", items
    assert until(lambda: cam(page, "cam2", "e => e.dataset.led") == word, 20)
    # the page hears the check switched off by its event stream: on a busy machine, a moment later
    # (the LED's word above may have been the same all along, as with led_before False)
    shown = "e => [e.dataset.aim, getComputedStyle(e.querySelector('.frame')).display]"
    assert until(lambda: cam(page, "cam2", shown) == ["off", "block"], 20), cam(page, "cam2", shown)


def test_a_camera_a_recording_feeds_is_refused_in_one_sentence(live, page):
    hub, src = live.console.hub, live.rig.sources["cam2"]
    # an action from elsewhere (no page token) is refused before anything
    r = requests.post(live.url + "aim/cam2", json={"on": True}, timeout=10)
    assert r.status_code == 403 and not live.console.aim.view("cam2")["on"]
    hub.attach(["cam2"])  # a scan (or the daily QA) records cam2
    try:
        page.click('section[data-camera="cam2"] button.aim-on')
        assert until(lambda: cam(page, "cam2", "e => e.querySelector('.aim-error').textContent"), 10)
        said = cam(page, "cam2", "e => e.querySelector('.aim-error').textContent")
        assert said == (
            "not checked: cam2 is recording (a scan or the daily QA has its frames and its LED); "
            "the check goes on when that is done"
        ), said
        assert "\n" not in said and not live.console.aim.view("cam2")["on"]
    finally:
        hub.detach(["cam2"])
    # switched on, then a recording takes it: the page says so, the LED untouched; back to checks after
    n0 = checks_done(live, "cam2")
    click_aim(page, live, "cam2", True)
    assert until(lambda: checks_done(live, "cam2") > n0 and not live.console.aim.view("cam2")["busy"], 60)
    led = src.led_on()
    hub.attach(["cam2"])
    try:
        assert until(lambda: cam(page, "cam2", "e => e.dataset.aim") == "not-checked", 30), why(live, "cam2")
        problem = cam(page, "cam2", "e => e.querySelector('.aim-problem').textContent")
        assert problem.startswith("not checked: cam2 is recording") and "(the verdicts below are of check" in problem
        assert cam(page, "cam2", "e => e.querySelector('.aim-side').classList.contains('old')")
        n = checks_done(live, "cam2")
        page.wait_for_timeout(3000)
        assert checks_done(live, "cam2") == n and src.led_on() == led
    finally:
        hub.detach(["cam2"])
    assert until(lambda: checks_done(live, "cam2") > n, 60)
    assert until(lambda: cam(page, "cam2", "e => e.dataset.aim") in ("good", "adjust"), 20)


def test_an_led_that_does_not_switch_or_a_camera_that_does_not_say_is_not_checked_and_said(live, page):
    src, server = live.rig.sources["cam2"], live.rig.servers["cam2"]
    src.set_led(True)
    server.faults.led_held = True  # an action rule holds the output: the camera answers OK, the LED stays on
    try:
        click_aim(page, live, "cam2", True)
        assert until(lambda: cam(page, "cam2", "e => e.dataset.aim") == "not-checked", 30), why(live, "cam2")
        said = cam(page, "cam2", "e => e.querySelector('.aim-problem').textContent")
        assert said.startswith(
            "not checked: switched off here, but the camera says its LED output is on: the switch did not take"
        ), said
        assert src.led_on()
    finally:
        server.faults.led_held = False
    server.faults.offline = True  # off the network: its LED state is not known, nothing is switched
    try:
        assert until(
            lambda: cam(page, "cam2", "e => e.querySelector('.aim-problem').textContent").startswith(
                "not checked: the LED state of cam2 is not known (the camera did not say"
            ),
            40,
        ), cam(page, "cam2", "e => e.querySelector('.aim-problem').textContent")
    finally:
        server.faults.offline = False
    click_aim(page, live, "cam2", False)
    wait_idle(live, "cam2")
    assert src.led_on()
