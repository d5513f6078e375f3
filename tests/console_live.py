"""The room console for the tests, the screenshots and the benchmark, and the browser they look
at it with.

* ``LiveConsole``: served in this process, for those that need its objects at hand (the marker
  names the Scan page feeds, the facts, the QA jobs): the same objects `vts console` builds
  (console/serve.py, its ``bind`` and ``_Server``), uvicorn on 127.0.0.1 in a thread, the facts
  kept fresh by a thread as serve() keeps them; ``qa_rig_yaml``: a simulated rig's rig.yaml for
  the Daily QA page.
* ``start_console``/``stop_console``: `vts console` as users run it, a subprocess; ``run_vts``:
  any `vts` command to its end.
* ``chromium()``/the ``browser`` fixture: Debian's /usr/bin/chromium through Playwright (never
  `playwright install`), headless; ``cam``/``click_led``: a Room page's camera; ``until``: one
  poll-until-true; ``wait_js``: a page's JavaScript until true (within the console's CSP).
"""

from __future__ import annotations

import contextlib
import re
import selectors
import signal
import subprocess
import sys
import threading
import time

import pytest

CHROMIUM = "/usr/bin/chromium"
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
VTS = [sys.executable, "-m", "vts_hw.cli"]


def until(check, timeout=20.0, poll=0.05):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        got = check()
        if got:
            return got
        time.sleep(poll)
    return check()


def wait_js(page, js: str, arg=None, timeout: float = 30_000):
    """``page.wait_for_function(js, arg=arg, timeout=timeout)`` without it: Playwright's polls with
    the page's ``eval``, which the console's Content-Security-Policy forbids (no 'unsafe-eval');
    ``page.evaluate`` is the browser's own. What ``js`` gave once true; TimeoutError after ``timeout`` ms."""
    end = time.monotonic() + timeout / 1000
    while True:
        got = page.evaluate(js, arg)
        if got:
            return got
        if time.monotonic() > end:
            raise TimeoutError(f"not true within {timeout / 1000:g} s: {js}")
        page.wait_for_timeout(100)  # (Playwright tells its events meanwhile)


class LiveConsole:
    """``with LiveConsole(cameras, rig_name, open_store) as live:`` -> ``live.url``,
    ``live.console``, ``live.hub``, ``live.names``, ``live.facts``, ``live.phantom``. ``rig_config``: the rig the
    pages that run procedures (Daily QA) run them on. On leaving, a daily QA still running is
    waited for (30 s at most) before the hub closes."""

    def __init__(
        self,
        cameras: dict,
        rig: str,
        open_store=None,
        *,
        marker_hz: float = 5.0,
        idle_close_s: float = 2.0,
        facts_tick_s: float = 0.5,
        rig_config=None,
    ):
        from vts_hw.console.app import Console
        from vts_hw.console.hub import FramesHub
        from vts_hw.console.markers import MarkerWorker
        from vts_hw.console.names import MarkerNames
        from vts_hw.console.phantom import PhantomNames
        from vts_hw.console.room import RoomFacts

        self.names = MarkerNames()
        self.hub = FramesHub(cameras, idle_close_s=idle_close_s)
        # the phantom's spheres named as `vts console` names them: from the rig config's calibration and mapping
        self.phantom = PhantomNames.for_rig(self.names, rig_config)
        self.markers = MarkerWorker(self.hub, marker_hz, self.names, phantom=self.phantom)
        self.facts = RoomFacts(cameras, rig, open_store, names=self.names)
        self.console = Console(rig, self.hub, self.markers, self.facts, open_store=open_store, rig_config=rig_config)
        self._tick = facts_tick_s
        self._stop = threading.Event()

    def __enter__(self) -> LiveConsole:
        import uvicorn

        from vts_hw.console.app import create_app
        from vts_hw.console.serve import _Server, bind

        self._facts = threading.Thread(target=self._keep_facts, daemon=True)
        self._facts.start()
        self.sock = bind("127.0.0.1", 0)
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}/"
        started = threading.Event()
        config = uvicorn.Config(
            create_app(self.console), log_level="warning", access_log=False, lifespan="off", timeout_graceful_shutdown=2
        )
        self.server = _Server(config, started.set, self.console.closing.set)
        self._serve = threading.Thread(target=self.server.run, args=([self.sock],), daemon=True)
        self._serve.start()
        assert started.wait(30), "the console did not start"
        return self

    def _keep_facts(self):
        while not self._stop.is_set():
            try:
                self.facts.refresh_due()
            except Exception:  # as serve() does: the page says what it could not read
                pass
            self._stop.wait(self._tick)

    def __exit__(self, *exc) -> None:
        self.server.server.should_exit = True
        self._serve.join(15)
        self._stop.set()
        self._facts.join(10)
        self.console.qa_jobs.wait(30)
        self.console.aim.close()
        self.markers.close()
        self.hub.close()
        self.sock.close()


@contextlib.contextmanager
def served_room(rig, cams: dict, db, **kw):
    """A LiveConsole (``live.rig``: ``rig``) on the simulated rig's open cameras ``cams`` and the
    results store ``db`` (read-only), as `vts console` serves them; on leaving, the cameras are
    closed and the rig's faults put back."""
    from vts_hw.store import ResultsStore

    name = (kw.get("rig_config") or rig.config()).rig
    try:
        with LiveConsole(cams, name, lambda: ResultsStore(db, mode="read"), **kw) as live:
            live.rig = rig
            yield live
    finally:
        for c in cams.values():
            c.close()
        for srv in rig.servers.values():
            srv.faults.reset()


def led_form_from_another_site(browser_or_context, url: str, on: bool) -> list[int]:
    """A page of another site (another origin on this machine: Chromium keeps public sites off
    loopback addresses anyway) that posts a form to the console's LED switch (JSON as
    text/plain), opened in the browser; the statuses of the console's answers to it."""
    other = "http://localhost:9/elsewhere"
    pg = browser_or_context.new_page()
    pg.route(
        other,
        lambda route: route.fulfill(
            content_type="text/html",
            body=f"""
        <form id=f method=post action="{url}camera/cam1/led" enctype="text/plain">
        <input name='{{"on": {str(on).lower()}, "x": "' value='"}}'></form>
        <script>document.getElementById("f").submit()</script>""",
        ),
    )
    statuses: list[int] = []
    pg.on("response", lambda resp: statuses.append(resp.status) if resp.url.endswith("/camera/cam1/led") else None)
    pg.goto(other)
    for _ in range(100):  # (Playwright tells its events while it is called)
        if statuses:
            break
        pg.wait_for_timeout(200)
    pg.close()
    return statuses


def qa_rig_yaml(rig, folder):
    """The simulated rig's rig.yaml for the Daily QA page: its store ``folder/results.sqlite``,
    the QATrack+ push without the attached report (seconds per run, not what is shown)."""
    import yaml

    path, _ = rig.write(folder)
    data = yaml.safe_load(path.read_text())
    data["store"] = {"url": f"sqlite:///{folder / 'results.sqlite'}"}
    data["qatrack"].update(report="none", plots=False)
    path.write_text(yaml.safe_dump(data))
    return path


FORM_TOKEN = re.compile(r'name="csrf_token" value="([^"]+)"')


def log_in(client, name: str, password: str, next_: str = "/", **kw):
    """POST the login form as a browser does (Starlette's TestClient ``client``): the form shown
    first, its token (and the cookie that goes with it) sent back with the fields."""
    shown = client.get("/login")
    m = FORM_TOKEN.search(shown.text)
    assert m, (shown.status_code, shown.text[:200])
    return client.post(
        "/login",
        data={"name": name, "password": password, "next": next_, "csrf_token": m.group(1)},
        follow_redirects=False,
        **kw,
    )


def log_in_over_http(session, url: str, name: str, password: str, **kw):
    """The same over the network (a ``requests.Session`` ``session``, the console at ``url``)."""
    shown = session.get(url + "login", timeout=30, **kw)
    m = FORM_TOKEN.search(shown.text)
    assert m, (shown.status_code, shown.text[:200])
    return session.post(
        url + "login", data={"name": name, "password": password, "csrf_token": m.group(1)}, timeout=30, **kw
    )


def start_console(args, env, timeout=60.0):
    """`vts console ARGS` in the background; (process, url) once it printed its address."""
    p = subprocess.Popen([*VTS, "console", *args], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    sel = selectors.DefaultSelector()
    sel.register(p.stdout, selectors.EVENT_READ)
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if sel.select(0.2):
            line = p.stdout.readline()
            if "open http" in line:
                return p, line.split("open ", 1)[1].split()[0]
            if not line:
                break
    p.kill()
    raise AssertionError(f"vts console did not start: {p.stderr.read()[-2000:]}")


def run_vts(args, env, timeout=60):
    """`vts ARGS` to its end: the completed process (its output as text)."""
    return subprocess.run([*VTS, *args], env=env, capture_output=True, text=True, timeout=timeout)


def stop_console(p) -> tuple[int, str, str]:
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=30)
    return p.returncode, out, err


@contextlib.contextmanager
def chromium(*extra_args):
    """Debian's Chromium, headless, through Playwright (closed on leaving)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=[*ARGS, *extra_args])
        try:
            yield b
        finally:
            b.close()


@pytest.fixture(scope="module")
def browser():
    """One Chromium for a test module (tests/conftest.py makes it every test's)."""
    with chromium() as b:
        yield b


def cam(page, name, what):
    """``what`` (a JS function) of the Room page's section of camera ``name``."""
    return page.eval_on_selector(f'section[data-camera="{name}"]', what)


def click_led(page, rig, name, on: bool):
    """The Room page's LED switch of ``name``: the simulated camera's LED and the page follow."""
    page.click(f'section[data-camera="{name}"] button.led-{"on" if on else "off"}')
    assert until(lambda: rig.servers[name].source.led_on() == on, 10)
    assert until(lambda: cam(page, name, "e => e.dataset.led") == ("on" if on else "off"), 10)
