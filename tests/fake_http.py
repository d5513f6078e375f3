"""A requests session that answers from a list: for the unit tests of a driver's reading of
replies no simulator sends (the shapes bench/fuzz.py found)."""

from __future__ import annotations

import requests


class Answers:
    """Answers each request with the next JSON body, or the next ``(status, body)``."""

    verify = True

    def __init__(self, *answers):
        self.answers = list(answers)

    def request(self, method, url, params=None, **_):
        answer = self.answers.pop(0)
        status, body = answer if isinstance(answer, tuple) else (200, answer)
        r = requests.Response()
        r.status_code, r._content, r._content_consumed = status, body, True  # read whole, as requests leaves it
        r.headers["Content-Type"] = "application/json"
        r.request = requests.Request(method, url, params=params).prepare()
        r.url = r.request.url
        return r

    def close(self) -> None:
        pass
