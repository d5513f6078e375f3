"""The real QATrack+ for the tests: ../shared/interop/qatrack/run-qatrack.sh, started early.

The script sets up QATrack+ 3.1 (Django 2.2, DRF) on 127.0.0.1 in ``$QAT`` (default
/tmp/qatrack-real): about 6 minutes the first time on 2 cores (it installs QATrack+'s
requirements and migrates), seconds once cached. conftest.py starts it in the background as
soon as the session's tests are collected, if any is marked ``real_qatrack``, and runs those
tests last, so that the install overlaps the rest of the suite; the fixture waits for it.
The server is stopped at the end of the session if the session started it.
"""

from __future__ import annotations

import os
import re
import subprocess
import time
from pathlib import Path

import requests

REPO = Path(__file__).resolve().parents[1]
SCRIPT = Path(os.environ.get("VTS_QATRACK_SCRIPT", REPO.parent / "shared" / "interop" / "qatrack" / "run-qatrack.sh"))
QAT = Path(os.environ.get("QAT", "/tmp/qatrack-real"))
PORT = int(os.environ.get("VTS_QATRACK_PORT", "8765"))
START_TIMEOUT_S = 25 * 60


class RealQATrack:
    """The server run-qatrack.sh runs: its URL, tokens, zone; restart in another zone; stop."""

    def __init__(self):
        self.url = f"http://127.0.0.1:{PORT}/"
        self.zone = None
        self._starter: subprocess.Popen | None = None
        self.log = QAT.parent / f"{QAT.name}-start.log"
        self.was_running = self.answering()
        self.started_by_us = False

    # -- life -------------------------------------------------------------------------------

    def _env(self, zone: str | None) -> dict:
        env = {**os.environ, "QAT": str(QAT), "PORT": str(PORT)}
        env.pop("QATRACK_DB", None)
        if zone:
            env["QATRACK_TIME_ZONE"] = zone
        return env

    def start_in_background(self, zone: str = "America/Toronto") -> None:
        if self._starter is not None:
            return
        assert SCRIPT.is_file(), f"the real QATrack+ script is missing: {SCRIPT} (../shared beside the checkout)"
        QAT.parent.mkdir(parents=True, exist_ok=True)
        if self.was_running:        # someone's server: restart it in our zone so that we know its zone
            self.stop()
        self.zone = zone
        self.started_by_us = True
        with open(self.log, "w") as log:
            self._starter = subprocess.Popen([str(SCRIPT), "start"], env=self._env(zone), stdout=log,
                                             stderr=subprocess.STDOUT, start_new_session=True)

    def wait(self) -> "RealQATrack":
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
        assert code == 0, f"run-qatrack.sh start failed ({code}):\n" + "\n".join(tail)
        assert self.answering(), "QATrack+ was started but does not answer:\n" + "\n".join(tail)
        return self

    def restart(self, zone: str) -> None:
        """Stop and start the server with TIME_ZONE ``zone`` (the site's setting)."""
        if zone == self.zone and self.answering():
            return
        self.stop()
        out = subprocess.run([str(SCRIPT), "start"], env=self._env(zone), capture_output=True, text=True,
                             timeout=600)
        assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
        self.zone = zone

    def stop(self) -> None:
        subprocess.run([str(SCRIPT), "stop"], env=self._env(None), capture_output=True, timeout=60)
        for _ in range(50):
            if not self.answering():
                return
            time.sleep(0.2)

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
        r = requests.get(url if url.startswith("http") else self.url + "api/" + url, params=params or None,
                         headers={"Authorization": f"Token {self.tokens['QATRACK_ADMIN_TOKEN']}"}, timeout=30)
        r.raise_for_status()
        return r.json()

    def instances(self, user_key: str) -> list[dict]:
        return self.get("qa/testlistinstances/", user_key=user_key)["results"]

    def values(self, instance: dict, _slugs: dict = {}) -> dict[str, dict]:   # noqa: B006 (a cache)
        """macro -> {value, skipped, comment} of an instance, each test's macro read from the site."""
        out = {}
        for ti in instance["test_instances"]:
            uti = ti["unit_test_info"]
            if uti not in _slugs:
                _slugs[uti] = self.get(self.get(uti)["test"])["slug"]
            out[_slugs[uti]] = {"value": ti["value"], "skipped": ti["skipped"], "comment": ti["comment"]}
        return out
