"""One conversation with a QATrack+ site, the real one or the stand-in, answer by answer.

Every request the push sends or could meet (tokens, the assignment list, instances by key, a
post with values, a skipped test, a comment and an attachment, and each refusal: work times
with an offset or in the hour the clocks repeat or skip, a missing test, a wrong value type, a
hyperlink to nothing, bad attachments, a user key used twice, a missing slash, a wrong base
URL, a user without the permission to add), and each answer reduced to what must agree: the
status, the kind of body, the Location and WWW-Authenticate headers, and the JSON's keys and
values, with what the site makes up itself (times of creation, ids, tokens, its references)
reduced to its kind.

Record the real server's answers once (tests/interop/test_qatrack_peer.py compares the stand-in with them):

    ../shared/interop/qatrack/run-qatrack.sh            # a real QATrack+ 3.1 on 127.0.0.1:8765
    .venv/bin/python tests/qatrack_conversation.py record [--qat /tmp/qatrack-real]

It makes a user without permissions on that site (through its manage.py), talks to it as the
site's setup_site.py made it (unit "SPECT room 1", list "VTS daily" of nine tests, time zone
America/Toronto) and writes tests/data/qatrack_real_answers.json.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import subprocess
import sys
import uuid
from pathlib import Path

import requests

HERE = Path(__file__).resolve().parent
FIXTURE = HERE / "data" / "qatrack_real_answers.json"
UNIT = "SPECT room 1"
DAILY_LIST = "VTS daily"
DAILY = ["cam1_dx", "cam1_dy", "cam2_dx", "cam2_dy", "cam1_sd", "cam2_sd", "cam1_missing", "cam2_missing", "cam3_dx"]
TIME_ZONE = "America/Toronto"
# what the site makes up itself: only its kind is compared
VOLATILE = {
    "created",
    "modified",
    "submit_date",
    "due_date",
    "token",
    "last_instance",
    "pass_fail",
    "reference",
    "tolerance",
    "status",
    "value_display",
    "diff_display",
    "frequency",
    "auto_schedule",
    "assigned_to",
    "visible_to",
    "content_type",
    "object_id",
    "tests_object",
    "next_test_list",
    "unit",
    "created_by",
    "modified_by",
    "user",
    "unit_test_info",
    "order",
}
URL_RE = re.compile(r"^(https?://[^/]+)?(/(api|qc|qa|media|accounts)\b.*)$")


class Context:
    """The site's address and tokens, and what the conversation learned on the way."""

    def __init__(self, root: str, token: str, noperm_token: str, user: str, password: str):
        self.root = root if root.endswith("/") else root + "/"
        self.api = self.root + "api/"
        self.token, self.noperm_token, self.user, self.password = token, noperm_token, user, password
        self.suffix = uuid.uuid4().hex[:10]
        self.created: str | None = None

    def h(self, token: str | None = None) -> dict:
        return {"Authorization": f"Token {token or self.token}", "Accept": "application/json"}

    def key(self, name: str) -> str:
        return f"conv-{name}-{self.suffix}"

    def utc(self, form: str = "qc", n: int = 1) -> str:
        return f"{self.api}{form}/unittestcollections/{n}/"


def _tests(**over) -> dict:
    out = {m: {"value": 0.25 + k / 8} for k, m in enumerate(DAILY)}
    out.update(over)
    return {k: v for k, v in out.items() if v is not None}


def _post(c: Context, name: str, url: str | None = None, token: str | None = None, **body):
    data = {
        "unit_test_collection": c.utc(),
        "day": 0,
        "in_progress": False,
        "include_for_scheduling": True,
        "work_started": "2026-11-20 07:30:00",
        "work_completed": "2026-11-20 07:31:15",
        "user_key": c.key(name),
        "comment": f"conversation {name}",
        "tests": _tests(),
    }
    data.update(body)
    data = {k: v for k, v in data.items() if v is not None}
    return requests.post(
        url or c.api + "qa/testlistinstances/", json=data, headers=c.h(token), allow_redirects=False, timeout=30
    )


def _post_ok(c: Context):
    r = _post(
        c,
        "ok",
        tests=_tests(cam3_dx={"skipped": True, "comment": "no cam3"}, extra_macro={"value": 1}),
        attachments=[{"filename": "vts-note.txt", "value": "aGVsbG8gUUFUcmFjaysK", "encoding": "base64"}],
    )
    if r.status_code == 201:
        c.created = r.json().get("url")
    return r


def _get(c: Context, path: str, token: str | None = "default", **params):
    headers = {} if token is None else c.h(None if token == "default" else token)
    return requests.get(
        path if path.startswith("http") else c.api + path,
        params=params or None,
        headers=headers,
        allow_redirects=False,
        timeout=30,
    )


STEPS = [
    (
        "token_form",
        lambda c: requests.post(c.api + "get-token/", data={"username": c.user, "password": c.password}, timeout=30),
    ),
    (
        "token_json",
        lambda c: requests.post(c.api + "get-token/", json={"username": c.user, "password": c.password}, timeout=30),
    ),
    (
        "token_wrong_password",
        lambda c: requests.post(c.api + "get-token/", data={"username": c.user, "password": "not-it"}, timeout=30),
    ),
    ("no_credentials", lambda c: _get(c, "qa/unittestcollections/", token=None)),
    ("wrong_token", lambda c: _get(c, "qa/unittestcollections/", token="0123456789abcdef0123456789abcdef01234567")),
    (
        "assignment",
        lambda c: _get(c, "qa/unittestcollections/", unit__name=UNIT, test_list__name=DAILY_LIST, active="true"),
    ),
    (
        "assignment_of_no_unit",
        lambda c: _get(
            c, "qa/unittestcollections/", unit__name="No such unit", test_list__name=DAILY_LIST, active="true"
        ),
    ),
    ("key_not_there", lambda c: _get(c, "qa/testlistinstances/", user_key=c.key("ok"))),
    ("post_ok", _post_ok),
    ("key_there", lambda c: _get(c, "qa/testlistinstances/", user_key=c.key("ok"))),
    ("instance", lambda c: _get(c, c.created or c.api + "qc/testlistinstances/999999/")),
    ("post_same_key", lambda c: _post(c, "ok")),
    ("post_qa_link", lambda c: _post(c, "qa-link", unit_test_collection=c.utc("qa"))),
    (
        "post_seconds_fraction",
        lambda c: _post(
            c, "fraction", work_started="2026-11-20 07:30:00.250000", work_completed="2026-11-20 07:31:15.750000"
        ),
    ),
    (
        "post_day_month_name",
        lambda c: _post(c, "monthname", work_started="20 Nov 2026 07:30", work_completed="20 Nov 2026 07:31:15"),
    ),
    (
        "post_iso_offset",
        lambda c: _post(
            c, "offset", work_started="2026-11-20T12:30:00+00:00", work_completed="2026-11-20T12:31:15+00:00"
        ),
    ),
    (
        "post_zulu_read_as_local",
        lambda c: _post(
            c, "zulu", work_started="2026-11-20T12:30:00.000000Z", work_completed="2026-11-20T12:31:15.000000Z"
        ),
    ),
    (
        "post_repeated_hour",
        lambda c: _post(c, "repeated", work_started="2026-11-01 01:30:00", work_completed="2026-11-01 01:40:00"),
    ),
    (
        "post_skipped_hour",
        lambda c: _post(c, "skipped", work_started="2026-03-08 02:30:00", work_completed="2026-03-08 02:40:00"),
    ),
    (
        "post_summer_time",
        lambda c: _post(c, "summer", work_started="2026-07-01 09:00:00", work_completed="2026-07-01 09:05:00"),
    ),
    ("post_no_work_started", lambda c: _post(c, "nostart", work_started=None)),
    (
        "post_null_work_completed",
        lambda c: requests.post(
            c.api + "qa/testlistinstances/",
            headers=c.h(),
            timeout=30,
            json={
                "unit_test_collection": c.utc(),
                "tests": _tests(),
                "work_started": "2026-11-20 07:30:00",
                "work_completed": None,
            },
        ),
    ),
    ("post_completed_before_started", lambda c: _post(c, "backwards", work_completed="2026-11-20 07:00:00")),
    ("post_missing_test", lambda c: _post(c, "missing", tests=_tests(cam2_dy=None))),
    ("post_wrong_type", lambda c: _post(c, "wrongtype", tests=_tests(cam1_dx={"value": "high"}))),
    ("post_test_not_a_dict", lambda c: _post(c, "notdict", tests=_tests(cam1_dx=0.5))),
    ("post_tests_a_list", lambda c: _post(c, "testslist", tests=[1, 2])),
    ("post_no_assignment", lambda c: _post(c, "noutc", unit_test_collection=None)),
    ("post_assignment_not_there", lambda c: _post(c, "utc999", unit_test_collection=c.utc(n=99999))),
    ("post_assignment_not_a_link", lambda c: _post(c, "utcbad", unit_test_collection="http://elsewhere/x/1/")),
    ("post_attachment_not_base64", lambda c: _post(c, "b64", attachments=[{"filename": "a.txt", "value": "!!"}])),
    ("post_attachment_shape", lambda c: _post(c, "attshape", attachments=["a.txt"])),
    ("post_user_key_too_long", lambda c: _post(c, "long" + "x" * 260)),
    (
        "post_not_json",
        lambda c: requests.post(
            c.api + "qa/testlistinstances/",
            data="{not json",
            headers={**c.h(), "Content-Type": "application/json"},
            timeout=30,
        ),
    ),
    ("post_without_permission", lambda c: _post(c, "noperm", token=c.noperm_token)),
    (
        "patch_without_permission",
        lambda c: requests.patch(
            c.created or c.api + "qc/testlistinstances/1/", json={"comment": "x"}, headers=c.h(), timeout=30
        ),
    ),
    ("post_no_slash", lambda c: _post(c, "noslash", url=c.api + "qa/testlistinstances")),
    ("get_no_slash", lambda c: _get(c, "qa/unittestcollections")),
    ("wrong_base_url", lambda c: _get(c, c.root + "qatrack/api/qa/unittestcollections/")),
    ("api_path_not_there", lambda c: _get(c, "qa/no-such-thing/")),
]


def normalise_url(text: str, c: Context) -> str:
    m = URL_RE.match(text)
    path = m.group(2) if m else text
    path = path.replace(c.suffix, "<suffix>")
    path = re.sub(r"/\d+/", "/N/", path)
    path = re.sub(r"_\d{4}-\d{2}-\d{2}_[0-9a-f]{6}", "_<date>_<id>", path)  # a stored attachment's name
    return ("<site>" if m and m.group(1) else "") + path


def shape(value, c: Context, key: str = ""):
    """``value`` with what the site makes up reduced to its kind."""
    if key in VOLATILE:
        return "<the site's>"
    if isinstance(value, dict):
        return {k: shape(v, c, k) for k, v in sorted(value.items())}
    if isinstance(value, list):
        return [shape(v, c, key) for v in value]
    if isinstance(value, str):
        if key == "comment" and value.startswith("Uploaded "):
            return "<upload comment>"
        if URL_RE.match(value):
            return normalise_url(value, c)
        return value.replace(c.suffix, "<suffix>")
    return value


def answer(r: requests.Response, c: Context) -> dict:
    kind = (r.headers.get("Content-Type") or "").split(";")[0].strip()
    out: dict = {
        "status": r.status_code,
        "body": "json" if kind == "application/json" else ("empty" if not r.content else kind),
    }
    if r.headers.get("Location"):
        out["location"] = normalise_url(r.headers["Location"], c)
    if r.headers.get("WWW-Authenticate"):
        out["www_authenticate"] = r.headers["WWW-Authenticate"]
    if kind == "application/json":
        out["json"] = shape(r.json(), c)
    return out


def converse(c: Context) -> list[dict]:
    return [{"step": name, "answer": answer(step(c), c)} for name, step in STEPS]


def _noperm_token(qat: Path) -> str:
    """A token of a user with no permissions, made in the real site through its manage.py."""
    code = (
        "from django.contrib.auth.models import User\nfrom rest_framework.authtoken.models import Token\n"
        "u, _ = User.objects.get_or_create(username='noperm')\n"
        "print('TOKEN=' + Token.objects.get_or_create(user=u)[0].key)\n"
    )
    env = {**os.environ, "QATRACK_DB": str(qat / "site" / "qatrack.db")}
    out = subprocess.run(
        [str(qat / "venv/bin/python"), "-W", "ignore", "manage.py", "shell", "-c", code],
        cwd=qat / "src" / "qatrackplus",
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return re.search(r"TOKEN=(\w+)", out.stdout).group(1)


def record(qat: Path, root: str) -> None:
    env = dict(re.findall(r"export (\w+)=(\S+)", (qat / "site" / "tokens.env").read_text()))
    c = Context(root, env["QATRACK_TOKEN"], _noperm_token(qat), env["QATRACK_USER"], env["QATRACK_PASSWORD"])
    answers = converse(c)
    FIXTURE.parent.mkdir(exist_ok=True)
    FIXTURE.write_text(
        json.dumps(
            {
                "what": "a real QATrack+ 3.1 (qatrackplus master of 2025-01-24, Django 2.2.28, DRF 3.12.2) answering "
                "tests/qatrack_conversation.py; site as ../shared/interop/qatrack/setup_site.py makes it",
                "command": "../shared/interop/qatrack/run-qatrack.sh && .venv/bin/python tests/qatrack_conversation.py record",
                "recorded": _dt.date.today().isoformat(),
                "time_zone": TIME_ZONE,
                "answers": answers,
            },
            indent=1,
        )
        + "\n"
    )
    print(f"{len(answers)} answers written to {FIXTURE}")


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("verb", choices=["record"])
    ap.add_argument(
        "--qat",
        type=Path,
        default=Path(os.environ.get("QAT", "/tmp/qatrack-real")),
        help="run-qatrack.sh's work folder (default $QAT or /tmp/qatrack-real)",
    )
    ap.add_argument("--url", default=f"http://127.0.0.1:{os.environ.get('PORT', '8765')}/")
    a = ap.parse_args()
    record(a.qat, a.url)
    sys.exit(0)
