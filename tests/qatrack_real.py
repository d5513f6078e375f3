"""The real QATrack+ for the tests: ../shared/interop/qatrack/run-qatrack.sh, started early.

The script sets up QATrack+ 3.1 (Django 2.2, DRF) on 127.0.0.1 in ``$QAT`` (default
/tmp/qatrack-real): about 6 minutes the first time on 2 cores (it installs QATrack+'s
requirements and migrates), seconds once cached. conftest.py starts it in the background as
soon as the session's tests are collected, if any is marked ``real_qatrack``, and runs those
tests last, so that the install overlaps the rest of the suite; the fixture waits for it.
The server is stopped at the end of the session if the session started it.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import threading
import time
from pathlib import Path

import requests

from vts_hw.lifeline import alive

REPO = Path(__file__).resolve().parents[1]
SCRIPT = Path(os.environ.get("VTS_QATRACK_SCRIPT", REPO.parent / "shared" / "interop" / "qatrack" / "run-qatrack.sh"))
QAT = Path(os.environ.get("QAT", "/tmp/qatrack-real"))
PORT = int(os.environ.get("VTS_QATRACK_PORT", "8765"))
START_TIMEOUT_S = 25 * 60
SITE_ZONE = "America/Toronto"  # the zone the server is first started in (QATrack+'s own default)
LATE_START_S = 300  # beyond the script's own 60 s for the server to answer (a loaded machine)


class RealQATrack:
    """The server run-qatrack.sh runs: its URL, tokens, zone; restart in another zone; stop."""

    def __init__(self):
        self.url = f"http://127.0.0.1:{PORT}/"
        self.zone = None
        self._starter: subprocess.Popen | None = None
        self.log = QAT.parent / f"{QAT.name}-start.log"
        self.done = QAT.parent / f"{QAT.name}-start.done"  # the start's outcome, for xdist workers
        self.was_running = self.answering()
        self.started_by_us = False

    # -- life -------------------------------------------------------------------------------

    def _env(self, zone: str | None) -> dict:
        env = {**os.environ, "QAT": str(QAT), "PORT": str(PORT)}
        env.pop("QATRACK_DB", None)
        if zone:
            env["QATRACK_TIME_ZONE"] = zone
        return env

    def start_in_background(self, zone: str = SITE_ZONE) -> None:
        if self._starter is not None:
            return
        assert SCRIPT.is_file(), f"the real QATrack+ script is missing: {SCRIPT} (../shared beside the checkout)"
        QAT.parent.mkdir(parents=True, exist_ok=True)
        if self.was_running:  # someone's server: restart it in our zone so that we know its zone
            self.stop()
        self.zone = zone
        self.started_by_us = True
        with open(self.log, "w") as log:
            self._starter = subprocess.Popen(
                [str(SCRIPT), "start"],
                env=self._env(zone),
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )

    def wait(self) -> RealQATrack:
        """Until the background start has ended and the API answers; AssertionError with the
        script's last lines when it failed."""
        if self._starter is None:
            self.start_in_background()
        try:
            code = self._starter.wait(timeout=START_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self._starter.kill()
            code = "timeout"
        tail = self.log.read_text(errors="replace").splitlines()[-15:] if self.log.exists() else []
        assert code == 0 or self._late_but_up("\n".join(tail)), f"run-qatrack.sh start failed ({code}):\n" + "\n".join(
            tail
        )
        assert self.answering(), "QATrack+ was started but does not answer:\n" + "\n".join(tail)
        return self

    def _late_but_up(self, said: str) -> bool:
        """The script gives the server about 60 s to answer; on a loaded machine Django can take
        longer, and the server it started goes on starting: wait for it (a hang detector)."""
        pid = self._server_pid()
        if "did not come up" not in said or pid is None or not alive(pid):
            return False
        deadline = time.monotonic() + LATE_START_S
        while time.monotonic() < deadline:
            if self.answering():
                return True
            time.sleep(1)
        return False

    def note_when_started(self) -> None:
        """In the process that started the server (an xdist controller): a thread waits for the
        start to end and writes its outcome to ``self.done`` (the workers wait for that file)."""
        with contextlib.suppress(FileNotFoundError):
            self.done.unlink()

        def note():
            try:
                self.wait()
                text = "ok"
            except AssertionError as e:
                text = f"failed: {e}"
            self.done.write_text(text)

        threading.Thread(target=note, daemon=True).start()

    def wait_for_other(self) -> RealQATrack:
        """In an xdist worker: until the start the controller began has ended (``self.done``),
        then the server must answer."""
        deadline = time.monotonic() + START_TIMEOUT_S + LATE_START_S
        while not self.done.exists() and time.monotonic() < deadline:
            time.sleep(1)
        outcome = self.done.read_text() if self.done.exists() else f"no outcome within {START_TIMEOUT_S} s"
        assert outcome == "ok", f"the real QATrack+ did not start: {outcome} (log: {self.log})"
        assert self.answering(), f"the real QATrack+ started but does not answer (log: {self.log})"
        self.zone = SITE_ZONE
        return self

    def restart(self, zone: str) -> None:
        """Stop and start the server with TIME_ZONE ``zone`` (the site's setting)."""
        if zone == self.zone and self.answering():
            return
        self.stop()
        out = subprocess.run([str(SCRIPT), "start"], env=self._env(zone), capture_output=True, text=True, timeout=600)
        assert out.returncode == 0 or self._late_but_up(out.stderr), out.stdout[-2000:] + out.stderr[-2000:]
        self.zone = zone

    def stop(self) -> None:
        """The script's stop (SIGTERM, 1 s), then until that process has gone and the port is
        free: on a loaded machine a server can outlive the script's second, and a start then
        finds the port taken while the old server (in the old zone) still answers."""
        pid = self._server_pid()
        subprocess.run([str(SCRIPT), "stop"], env=self._env(None), capture_output=True, timeout=60)
        deadline = time.monotonic() + 60
        while pid is not None and alive(pid) and time.monotonic() < deadline:
            time.sleep(0.2)
        if pid is not None and alive(pid):
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        while self.answering() and time.monotonic() < deadline + 10:
            time.sleep(0.2)

    @staticmethod
    def _server_pid() -> int | None:
        try:
            return int((QAT / "site" / "server.pid").read_text().strip())
        except (OSError, ValueError):
            return None

    def answering(self) -> bool:
        try:
            return requests.get(self.url + "api/", timeout=2).status_code in (200, 401, 403)
        except requests.RequestException:
            return False

    # -- the site ---------------------------------------------------------------------------

    @property
    def tokens(self) -> dict[str, str]:
        return dict(re.findall(r"export (\w+)=(\S+)", (QAT / "site" / "tokens.env").read_text()))

    def get(self, url: str, **params) -> dict:
        """A GET as the site's administrator (what the site shows)."""
        r = requests.get(
            url if url.startswith("http") else self.url + "api/" + url,
            params=params or None,
            headers={"Authorization": f"Token {self.tokens['QATRACK_ADMIN_TOKEN']}"},
            timeout=30,
        )
        r.raise_for_status()
        return r.json()

    def instances(self, user_key: str) -> list[dict]:
        return self.get("qa/testlistinstances/", user_key=user_key)["results"]

    def values(self, instance: dict, _slugs: dict = {}) -> dict[str, dict]:  # noqa: B006 (a cache)
        """macro -> {value, skipped, comment} of an instance, each test's macro read from the site."""
        out = {}
        for ti in instance["test_instances"]:
            uti = ti["unit_test_info"]
            if uti not in _slugs:
                _slugs[uti] = self.get(self.get(uti)["test"])["slug"]
            out[_slugs[uti]] = {"value": ti["value"], "skipped": ti["skipped"], "comment": ti["comment"]}
        return out
