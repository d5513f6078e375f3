"""Clients that ask the console for what its Scan page asks, without a browser (bench/console.py).

In the room the console serves the technologists' screens over the network: the browsers run on
other computers. On this 2-core bench machine two Chromiums beside the live path cost it more
than the console does. ``PageClient`` reads ``/scan/events`` and fetches each camera's picture
when told of a new one, at most ``PICTURE_EVERY_S`` apart per camera (as static/scan.js does),
so the console's own cost on the live path can be measured apart from the browsers' rendering.
"""

from __future__ import annotations

import json
import re
import threading
import time

import requests

PICTURE_EVERY_S = 0.5  # scan.js: PICTURE_EVERY_MS


class PageClient:
    """One Scan page's requests to the console at ``url``, in threads, until ``close()``:
    the event stream, and the pictures it announces. ``pictures``: how many were fetched."""

    def __init__(self, url: str):
        self.url = url
        self.pictures = 0
        self.errors: list[str] = []
        self._stop = threading.Event()
        self._want: dict[str, int] = {}
        self._cond = threading.Condition()
        self._session = requests.Session()
        self._threads = [
            threading.Thread(target=self._events, daemon=True),
            threading.Thread(target=self._fetch, daemon=True),
        ]
        for t in self._threads:
            t.start()

    def _events(self):
        try:
            with self._session.get(self.url + "scan/events", stream=True, timeout=(5, 30)) as r:
                event = None
                for line in r.iter_lines(decode_unicode=True):
                    if self._stop.is_set():
                        return
                    if line.startswith("event: "):
                        event = line[7:]
                    elif line.startswith("data: ") and event == "frame":
                        d = json.loads(line[6:])
                        with self._cond:
                            self._want[d["camera"]] = d["seq"]
                            self._cond.notify()
        except requests.RequestException as exc:
            if not self._stop.is_set():
                self.errors.append(f"events: {exc}")

    def _fetch(self):
        shown: dict[str, int] = {}
        fetched: dict[str, float] = {}
        while not self._stop.is_set():
            with self._cond:
                due = [c for c, s in self._want.items() if shown.get(c) != s]
                if not due:
                    self._cond.wait(0.2)
                    continue
            now = time.monotonic()
            for c in due:
                if now - fetched.get(c, float("-inf")) < PICTURE_EVERY_S:
                    continue
                fetched[c] = now
                try:
                    r = self._session.get(self.url + f"frame/{c}", timeout=10)
                    if r.ok:
                        shown[c] = int(r.headers.get("X-Frame-Seq", -1))
                        self.pictures += 1
                except requests.RequestException as exc:
                    self.errors.append(f"frame {c}: {exc}")
            self._stop.wait(0.05)

    def close(self):
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        self._session.close()
        for t in self._threads:
            t.join(5)


def start_scan(url: str, reference_s: float, duration_s: float) -> str:
    """POST /scan/start as the page does (its token from the page); the scan's folder name."""
    page = requests.get(url + "scan", timeout=10).text
    token = re.search(r'data-token="([^"]+)"', page).group(1)
    r = requests.post(
        url + "scan/start",
        json={"reference_s": reference_s, "duration_s": duration_s},
        headers={"X-Console-Token": token, "Origin": url.rstrip("/")},
        timeout=10,
    )
    if not r.ok:
        raise SystemExit(f"the console refused the scan: {r.text}")
    return r.json()["scan"]


def wait_stopped(url: str, timeout: float) -> dict:
    """The Scan page's state once the scan has stopped (or failed)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = requests.get(url + "scan/state", timeout=10).json()
        if v.get("phase") in ("stopped", "failed"):
            return v
        time.sleep(0.5)
    raise SystemExit("the scan did not stop")
