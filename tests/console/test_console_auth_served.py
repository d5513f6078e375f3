"""Who may do what on the console (issue 23 §3), with `vts console` as users run it (a
subprocess against a simulated rig, its users added by `vts console user add` into a real SQLite
store): HTTPS with a self-signed certificate (openssl) fetched with verification against it; and
in Debian's Chromium (Playwright), with --login on 127.0.0.1: the page goes to the login page, a
wrong password is refused, an operator logs in and switches the LED, the action is in the history
under her name, a cross-site POST is refused, logging out ends the session, a session ends when
idle and at its limit; no password, session cookie or camera password in any page, in the
console's output or in the store (but the hash). The hashing, sessions and the guard in process:
tests/console/test_console_auth.py.
"""

from __future__ import annotations

import os
import time

import pytest
import requests

from console_live import click_led, led_form_from_another_site, log_in_over_http, run_vts, start_console, stop_console
from test_console_auth import ANN_PW, PHIL_PW
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.tls import self_signed

pytestmark = pytest.mark.timeout(180)


@pytest.fixture(scope="module")
def login_rig(tmp_path_factory):
    """A simulated rig, its rig.yaml, and a results store with an operator and a physicist."""
    folder = tmp_path_factory.mktemp("login")
    db = folder / "results.sqlite"
    with SimRig(n_cameras=2, seed=7) as rig, rig.env():
        rig_yaml, _ = rig.write(folder)
        env = {
            **os.environ,
            **rig.env_vars(),
            "VTS_CONFIG": str(rig_yaml),
            "VTS_STORE": f"sqlite:///{db}",
            "ANN_PW": ANN_PW,
            "PHIL_PW": PHIL_PW,
        }
        for name, role, var in (("ann", "operator", "ANN_PW"), ("phil", "physicist", "PHIL_PW")):
            p = run_vts(["console", "user", "add", name, "--role", role, "--password-env", var], env)
            assert p.returncode == 0, p.stderr
        for v in ("ANN_PW", "PHIL_PW"):
            env.pop(v)  # the console itself never has them
        yield rig, env, db
        for srv in rig.servers.values():
            srv.faults.reset()


def test_https_with_the_given_certificate_checked_against_it(login_rig, tmp_path):
    _, env, _ = login_rig
    cert, key = self_signed(tmp_path)
    p, url = start_console(["--login", "--port", "0", "--certfile", str(cert), "--keyfile", str(key)], env)
    try:
        assert url.startswith("https://127.0.0.1:")
        r = requests.get(url + "login", verify=str(cert), timeout=10)
        assert r.status_code == 200 and "Log in to the room console" in r.text
        with pytest.raises(requests.exceptions.SSLError):
            requests.get(url + "login", timeout=10)  # not trusted without the certificate
        r = log_in_over_http(requests.Session(), url, "ann", ANN_PW, verify=str(cert), allow_redirects=False)
        assert r.status_code == 303
        cookie = r.headers["set-cookie"]
        assert cookie.startswith("__Host-vts_session=") and "; Secure" in cookie and "HttpOnly" in cookie
        r = requests.get(
            url + "session",
            cookies={"__Host-vts_session": r.cookies["__Host-vts_session"]},
            verify=str(cert),
            timeout=10,
        )
        assert r.json()["user"] == "ann"
    finally:
        code, out, err = stop_console(p)
    assert code == 0 and "Traceback" not in err, err


def _log_in(pg, name, password):
    pg.fill("#name", name)
    pg.fill("#password", password)
    pg.click("#login")


def test_in_chromium_an_operator_logs_in_switches_the_led_and_is_in_the_history(login_rig, browser):
    rig, env, db = login_rig
    p, url = start_console(["--login", "--port", "0"], env)
    seen: list[str] = []
    try:
        ctx = browser.new_context(viewport={"width": 1366, "height": 768})
        pg = ctx.new_page()
        pg.goto(url)
        assert "/login?next=%2F" in pg.url
        _log_in(pg, "ann", "not-her-password")
        pg.wait_for_selector("#login-error")
        assert pg.text_content("#login-error") == "wrong user name or password" and "/login" in pg.url
        _log_in(pg, "ann", ANN_PW)
        pg.wait_for_selector("section.camera")
        pg.wait_for_selector("#who")
        assert pg.text_content("#who").startswith("ann (operator)")
        cookie = next(c for c in ctx.cookies() if c["name"] == "vts_session")
        assert cookie["httpOnly"] and cookie["sameSite"] == "Strict"
        assert pg.evaluate("document.cookie") == ""  # not readable by a script
        click_led(pg, rig, "cam1", True)
        seen.append(pg.content())

        pg.goto(url + "history")
        pg.click("#to-actions")
        pg.wait_for_selector("tr.action")
        rows = pg.eval_on_selector_all(
            "tr.action", "rs => rs.map(r => [r.dataset.user, r.dataset.what, r.querySelector('.detail').textContent])"
        )
        assert rows[0][:2] == ["ann", "LED on"] and rows[0][2].startswith("camera: cam1"), rows
        assert "took: True" in rows[0][2], rows  # the camera said its LED is on (read back)
        assert ["ann", "logged in"] in [r[:2] for r in rows] and ["ann", "login refused"] in [r[:2] for r in rows]
        seen.append(pg.content())
        for path in ("api/room", "session", "history?state=OK", "history/actions?user=ann"):
            seen.append(ctx.request.get(url + path).text())

        # another site: its form posted in this browser carries no cookie (SameSite=Strict); a script with
        # the session's cookie but another Origin, or without the page's token, is refused
        statuses = led_form_from_another_site(ctx, url, False)
        assert statuses == [401], statuses
        jar = {"vts_session": cookie["value"]}
        r = requests.post(
            url + "camera/cam1/led",
            json={"on": False},
            cookies=jar,
            timeout=10,
            headers={"Origin": "http://elsewhere.example"},
        )
        assert r.status_code == 403 and "another site" in r.json()["error"]
        r = requests.post(url + "camera/cam1/led", json={"on": False}, cookies=jar, timeout=10)
        assert r.status_code == 403 and "console's page" in r.json()["error"]
        assert rig.servers["cam1"].source.led_on()  # untouched by them all

        pg.goto(url)
        click_led(pg, rig, "cam1", False)
        pg.wait_for_selector("#logout")
        pg.click("#logout")
        pg.wait_for_url("**/login")
        assert requests.get(url + "session", cookies=jar, timeout=10).status_code == 401
        pg.goto(url + "history")
        assert "/login?next=%2Fhistory" in pg.url
        ctx.close()
    finally:
        code, out, err = stop_console(p)
    assert code == 0 and "Traceback" not in err, err
    # nothing secret in a page, in the console's output, or in the store (but the hash)
    for secret in (ANN_PW, PHIL_PW, cookie["value"], rig.password):
        for text in (*seen, out, err):
            assert secret not in text
    stored = b"".join(f.read_bytes() for f in db.parent.iterdir() if f.name.startswith(db.name))
    assert b"scrypt$" in stored and b"LED on" in stored
    for secret in (ANN_PW, PHIL_PW, cookie["value"], rig.password):
        assert secret.encode() not in stored


def test_in_chromium_a_session_ends_when_idle_and_at_its_limit(login_rig, browser):
    _, env, _ = login_rig
    p, url = start_console(["--login", "--port", "0", "--session-idle", "5", "--session-max", "16"], env)
    try:
        s = requests.Session()  # logged in, then nothing for longer than the idle limit
        assert log_in_over_http(s, url, "phil", PHIL_PW).status_code == 200
        assert s.get(url + "session", timeout=10).json()["user"] == "phil"
        time.sleep(6.5)
        assert s.get(url + "session", timeout=10).status_code == 401

        ctx = browser.new_context(viewport={"width": 1366, "height": 768})
        pg = ctx.new_page()
        pg.goto(url)
        _log_in(pg, "phil", PHIL_PW)
        pg.wait_for_selector("#who")
        t0 = time.monotonic()
        pg.wait_for_timeout(8000)  # an open page keeps its session past the idle limit ...
        assert "/login" not in pg.url and pg.is_visible("#who")
        pg.wait_for_url("**/login?ended=1**", timeout=30_000)  # ... until its absolute limit
        assert time.monotonic() - t0 > 9
        assert pg.text_content("#login-note") == "your session has ended: log in again"
        ctx.close()
    finally:
        code, _, err = stop_console(p)
    assert code == 0 and "Traceback" not in err, err
