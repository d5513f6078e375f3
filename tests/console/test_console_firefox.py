"""The console's pages in Firefox (issue 23 §1: "in a current Chromium and Firefox").

Debian's ``firefox-esr`` (installed by `make test`'s Debian packages) driven through Mozilla's
own Marionette client (``marionette-driver``, PyPI; Marionette is built into Firefox: no
geckodriver, nothing downloaded). Playwright cannot drive it: its own Firefox build is a
download, and its WebDriver BiDi channel for a stock Firefox asks for commands Firefox ESR 153
does not have yet (docs/decisions/0066-room-led-and-names.md says what was tried).

* The Room page: each camera's picture updates (two different frames), the markers are drawn
  over it named (cam1's wall markers from its drift baseline), the LED switch switches the
  simulated camera's LED and the page shows the state read back, at 1366 x 768.
* The History page: the runs listed, filtered by a procedure and a state through the form, a
  run's page with its plot loaded and its measures.
"""

from __future__ import annotations

import shutil
import socket

import pytest

from console_live import LiveConsole, until
from history_store import fill
from vts_hw.drivers.registry import open_camera
from vts_hw.procedures.baseline import BaselineSet, take_baseline
from vts_hw.sim_devices.rig import SimRig
from vts_hw.store import ResultsStore
from vts_hw.store.recorder import record

FIREFOX = "/usr/bin/firefox-esr"
pytestmark = pytest.mark.timeout(300)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def firefox(tmp_path_factory):
    """A headless Firefox ESR under Marionette, in a profile of its own (removed after); its log
    in a temporary folder (by default mozrunner writes gecko.log where it is run)."""
    assert shutil.which(FIREFOX), f"{FIREFOX} is missing: `make debs` installs firefox-esr"
    import logging

    from marionette_driver.marionette import Marionette

    logging.getLogger("mozversion").setLevel(logging.WARNING)
    m = Marionette(
        host="127.0.0.1",
        port=free_port(),
        bin=FIREFOX,
        headless=True,
        app_args=["-no-remote"],
        startup_timeout=120,
        gecko_log=str(tmp_path_factory.mktemp("firefox-log") / "gecko.log"),
    )
    m.start_session()
    try:
        m.set_window_rect(width=1366, height=768)
        yield m
    finally:
        m.delete_session()
        m.cleanup()


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    folder = tmp_path_factory.mktemp("firefox")
    db = folder / "results.sqlite"
    ids = fill(db, folder)  # the History page's runs (rig room-h)
    with SimRig(n_cameras=2, seed=5) as rig, rig.env():
        cams = {c.name: open_camera(c) for c in rig.config().cameras}
        with ResultsStore(db) as store:  # cam1's wall markers, this rig's ("sim")
            record(store, BaselineSet([take_baseline(cams["cam1"], frames=2)]), rig="sim", operator="test")
        try:
            with LiveConsole(cams, "sim", lambda: ResultsStore(db, mode="read")) as lc:
                lc.rig, lc.ids = rig, ids
                yield lc
        finally:
            for c in cams.values():
                c.close()


def js(m, script: str, *args):
    return m.execute_script(script, script_args=list(args))


def test_the_room_page_in_firefox(firefox, live):
    m = firefox
    m.navigate(live.url)
    assert js(m, "return [window.innerWidth <= 1366, document.title]")[1].startswith("Room sim")
    seq = "return document.querySelector('section[data-camera=\"' + arguments[0] + '\"] img').dataset.seq || null"
    for name in ("cam1", "cam2"):
        first = until(lambda name=name: js(m, seq, name), 60)
        assert first, name
        assert until(lambda first=first, name=name: int(js(m, seq, name) or 0) > int(first), 30), name
        assert until(
            lambda name=name: (
                js(
                    m,
                    "return document.querySelector('section[data-camera=\"' + arguments[0] + '\"]').dataset.live",
                    name,
                )
                == "yes"
            ),
            20,
        )
    kinds = "return [...document.querySelectorAll('section[data-camera=\"cam1\"] svg circle')].map(c => c.dataset.kind)"
    assert until(lambda: (js(m, kinds) or []).count("wall") >= 3, 30), js(m, kinds)
    labels = js(
        m,
        "return [...document.querySelectorAll('section[data-camera=\"cam1\"] svg text.k-wall')]"
        ".map(t => t.textContent)",
    )
    assert labels and all(t.startswith("M") for t in labels)
    # the LED switch, read back (the baseline left it on)
    led = "return document.querySelector('section[data-camera=\"cam1\"]').dataset.led"
    assert until(lambda: js(m, led) == "on", 20)
    from marionette_driver.by import By

    m.find_element(By.CSS_SELECTOR, 'section[data-camera="cam1"] button.led-off').click()
    assert until(lambda: js(m, led) == "off", 15) and not live.rig.sources["cam1"].led_on()
    assert "OFF (read from the camera" in js(
        m, "return document.querySelector('section[data-camera=\"cam1\"] .led').textContent"
    )
    m.find_element(By.CSS_SELECTOR, 'section[data-camera="cam1"] button.led-on').click()
    assert until(lambda: js(m, led) == "on", 15) and live.rig.sources["cam1"].led_on()
    # both cameras fit the 1366 x 768 screen, side by side, without scrolling
    box = js(m, "return [document.documentElement.scrollWidth, document.documentElement.scrollHeight]")
    assert box[0] <= 1366 and box[1] <= 768, box


def test_the_history_page_in_firefox(firefox, live):
    from marionette_driver.by import By

    m = firefox
    m.navigate(live.url + "history")
    assert until(lambda: js(m, "return document.querySelectorAll('table.runs tbody tr').length") > 0, 20)
    m.find_element(By.CSS_SELECTOR, "select[name=procedure] option[value='sync check']").click()
    m.find_element(By.CSS_SELECTOR, "select[name=state] option[value='OK']").click()
    m.find_element(By.CSS_SELECTOR, "form.filters button[type=submit]").click()
    assert until(lambda: "procedure=sync+check&state=OK" in m.get_url(), 20), m.get_url()
    rows = "return [...document.querySelectorAll('table.runs tbody tr')].map(r => r.dataset.run)"
    assert until(lambda: js(m, rows) == [str(live.ids["sync"])], 20), js(m, rows)
    assert js(m, "return document.querySelector('table.runs tbody tr .st').textContent") == "OK"
    m.find_element(By.CSS_SELECTOR, f'tr[data-run="{live.ids["sync"]}"] td a').click()
    assert until(lambda: m.get_url().endswith(f"/history/run/{live.ids['sync']}"), 20), m.get_url()
    loaded = "const i = document.querySelector('img.plot'); return i && i.complete ? i.naturalWidth : 0"
    assert until(lambda: js(m, loaded) == 240, 20)
    assert "12" in js(m, "return document.querySelector('tr[data-metric=\"sync_max_abs_dt_ms\"] td.num').textContent")
    state = js(
        m, "const e = document.getElementById('run-state'); return [e.textContent, getComputedStyle(e).backgroundColor]"
    )
    assert state == ["OK", "rgb(220, 252, 231)"]
