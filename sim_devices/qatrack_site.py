"""The data and the rules of a simulated QATrack+ 3.1 site (no HTTP: that is qatrack_server.py).

What a real QATrack+ 3.1 (Django 2.2, Django REST framework 3.12) does with what the push
sends, as read in its sources (qatrack/api/qa/serializers.py ``TestListInstanceCreator``,
qatrack/settings.py) and as recorded from the real server (tests/data/qatrack_real_answers.json,
``tests/qatrack_conversation.py record``):

- work times: only the naive formats of QATrack+'s ``DATETIME_INPUT_FORMATS`` (an ISO time with
  an offset is "Datetime has wrong format"; its ``...Z`` form is read as a *local* time), made
  aware in the site's ``TIME_ZONE`` the way pytz does with ``is_dst=None``: a wall-clock time
  that happens twice or never there is 'Invalid datetime for the timezone "Zone".'; answered
  as ISO 8601 with the site's offset (``Z`` in UTC);
- field errors first (``{"field": [message]}``: required fields, hyperlinks that match no URL
  or no object, tests that are not dictionaries, bad attachments, a user key used before or
  longer than 255 characters), then the list's own rules in ``non_field_errors``: every test of
  the list present, numbers for numeric tests, work completed not before work started; values
  for macros the list does not have are dropped;
- hyperlinks answered under ``/api/qc/`` (QATrack+ mounts its QA API at both ``qa/`` and
  ``qc/``; reverse() gives the last), and accepted under either.
"""

from __future__ import annotations

import datetime as _dt
import re
from numbers import Number
from zoneinfo import ZoneInfo

BASE64_RE = re.compile(r"^([A-Za-z0-9+/]{4})*([A-Za-z0-9+/]{4}|[A-Za-z0-9+/]{3}=|[A-Za-z0-9+/]{2}==)$")
#: QATrack+'s settings.DATETIME_INPUT_FORMATS, and how DRF names them in its error
INPUT_FORMATS = [
    "%d %b %Y %H:%M",
    "%d %b %Y %H:%M:%S",
    "%Y-%m-%d %H:%M",
    "%Y-%m-%d %H:%M:%S",
    "%Y-%m-%d %H:%M:%S.%f",
    "%Y-%m-%dT%H:%M:%S.%fZ",
]
WRONG_FORMAT = (
    "Datetime has wrong format. Use one of these formats instead: DD [Jan-Dec] YYYY hh:mm, "
    "DD [Jan-Dec] YYYY hh:mm:ss, YYYY-MM-DD hh:mm, YYYY-MM-DD hh:mm:ss, YYYY-MM-DD hh:mm:ss.uuuuuu, "
    "YYYY-MM-DDThh:mm:ss.uuuuuuZ."
)
ATTACHMENT_SHAPE = (
    '`attachments` field must be list of form [{"filename": "file_name.txt", '
    '"value": "<base64 encoded bytes|text>", "encoding": "<base64|text>], ...]'
)
NO_PERMISSION = "You do not have permission to perform this action."
UTC_LINK = re.compile(r"^(?:https?://[^/]+)?/api/q[ac]/unittestcollections/(\d+)/$")


class FieldError(Exception):
    def __init__(self, message: str):
        super().__init__(message)
        self.message = message


def parse_work_time(value, zone: ZoneInfo) -> _dt.datetime:
    """A work time as DRF's DateTimeField reads it on a QATrack+ site in ``zone`` (aware)."""
    if value is None:
        raise FieldError("This field may not be null.")
    for fmt in INPUT_FORMATS:
        try:
            naive = _dt.datetime.strptime(value, fmt)
        except (ValueError, TypeError):
            continue
        first = naive.replace(tzinfo=zone, fold=0)
        if first.utcoffset() != naive.replace(tzinfo=zone, fold=1).utcoffset():
            raise FieldError(f'Invalid datetime for the timezone "{zone.key}".')  # twice or never
        return first
    raise FieldError(WRONG_FORMAT)


def show_time(value: _dt.datetime | None, zone: ZoneInfo) -> str | None:
    """DRF's ISO 8601 answer of an aware time, in the site's zone."""
    if value is None:
        return None
    text = value.astimezone(zone).isoformat()
    return text[:-6] + "Z" if text.endswith("+00:00") else text


class Site:
    """A QATrack+ site: ``lists`` (test list name -> its macros, all numeric), ``units`` (unit
    name -> test list names assigned), instances posted, in ``time_zone``."""

    def __init__(self, lists: dict[str, list[str]], units: dict[str, list[str]], time_zone: str = "America/Toronto"):
        self.lists = {name: list(macros) for name, macros in lists.items()}
        self.zone = ZoneInfo(time_zone)
        self.unit_names = sorted(units)
        self.utcs: list[dict] = []  # id, unit, test_list, active
        for unit, names in units.items():
            for name in names:
                self.utcs.append({"id": len(self.utcs) + 1, "unit": unit, "test_list": name, "active": True})
        self.instances: list[dict] = []
        self.attachment_count = 0

    # -- what the site answers --------------------------------------------------------------

    def utc_json(self, root: str, u: dict) -> dict:
        tl = f"{root}api/qc/testlists/{list(self.lists).index(u['test_list']) + 1}/"
        last = [i for i in self.instances if i["utc"] == u["id"]]
        return {
            "url": f"{root}api/qc/unittestcollections/{u['id']}/",
            "tests_object": tl,
            "next_test_list": tl,
            "next_day": 0,
            "due_date": None,
            "auto_schedule": False,
            "active": u["active"],
            "object_id": list(self.lists).index(u["test_list"]) + 1,
            "name": u["test_list"],
            "unit": f"{root}api/units/units/{self.unit_names.index(u['unit']) + 1}/",
            "frequency": None,
            "assigned_to": f"{root}api/auth/groups/2/",
            "content_type": f"{root}api/contenttypes/contenttypes/2/",
            "last_instance": f"{root}api/qc/testlistinstances/{last[-1]['id']}/" if last else None,
            "visible_to": [f"{root}api/auth/groups/2/"],
        }

    def _common(self, root: str, i: dict) -> dict:
        n = i["id"]
        utc = self.utcs[i["utc"] - 1]
        return {
            "url": f"{root}api/qc/testlistinstances/{n}/",
            "site_url": f"{root}qc/session/details/{n}/",
            "work_started": show_time(i["work_started"], self.zone),
            "work_completed": show_time(i["work_completed"], self.zone),
            "due_date": None,
            "in_progress": i["in_progress"],
            "flagged": False,
            "user_key": i["user_key"],
            "include_for_scheduling": i["include_for_scheduling"],
            "reviewed": None,
            "all_reviewed": False,
            "day": 0,
            "unit_test_collection": f"{root}api/qc/unittestcollections/{utc['id']}/",
            "test_list": f"{root}api/qc/testlists/{list(self.lists).index(utc['test_list']) + 1}/",
            "reviewed_by": None,
            "created_by": f"{root}api/auth/users/{i['user_id']}/",
        }

    def created_json(self, root: str, i: dict) -> dict:
        """The 201 answer (TestListInstanceCreator): ``tests`` by macro, the comment as sent."""
        tests = {}
        for k, (macro, t) in enumerate(i["tests"].items()):
            tests[macro] = {
                "url": f"/api/qc/testinstances/{i['ti0'] + k}/",
                "value": t["value"],
                "string_value": "",
                "date_value": None,
                "datetime_value": None,
                "value_display": "" if t["value"] is None else f"{t['value']:g}",
                "diff_display": "",
                "pass_fail": ["not_done", "Not Done"] if t["skipped"] else ["no_tol", "No Tol Set"],
                "skipped": t["skipped"],
                "comment": t["comment"],
                "status": "/api/qc/testinstancestatus/1/",
                "reference": None,
                "tolerance": None,
                "attachments": [],
            }
        return {**self._common(root, i), "comment": i["comment"], "tests": tests}

    def instance_json(self, root: str, i: dict) -> dict:
        """An instance as the list and detail views answer it (TestListInstanceSerializer)."""
        me = f"{root}api/qc/testlistinstances/{i['id']}/"
        user = f"{root}api/auth/users/{i['user_id']}/"
        created = show_time(i["created"], self.zone)
        tis = [
            {
                "url": f"{root}api/qc/testinstances/{i['ti0'] + k}/",
                "attachments": [],
                "review_date": None,
                "pass_fail": "not_done" if t["skipped"] else "no_tol",
                "value": t["value"],
                "string_value": "",
                "date_value": None,
                "datetime_value": None,
                "json_value": None,
                "skipped": t["skipped"],
                "comment": t["comment"],
                "work_started": show_time(i["work_started"], self.zone),
                "work_completed": show_time(i["work_completed"], self.zone),
                "order": k,
                "created": created,
                "modified": created,
                "status": f"{root}api/qc/testinstancestatus/1/",
                "reviewed_by": None,
                "reference": None,
                "tolerance": None,
                "unit_test_info": f"{root}api/qc/unittestinfos/{k + 1}/",
                "test_list_instance": me,
                "created_by": user,
                "modified_by": user,
            }
            for k, t in enumerate(i["tests"].values())
        ]
        atts = [
            {
                "url": f"{root}api/attachments/attachments/{a['id']}/",
                "attachment": f"{root}media/uploads/testlistinstance/{i['id']}/{a['stored']}",
                "label": a["filename"],
                "comment": f"Uploaded {i['created']} by {i['user']}",
                "test": None,
                "testlist": None,
                "testlistcycle": None,
                "testinstance": None,
                "testlistinstance": me,
                "created": created,
                "created_by": user,
            }
            for a in i["attachments"]
        ]
        comments = [{"url": "", "user": user, "submit_date": created, "comment": i["comment"]}] if i["comment"] else []
        return {
            **self._common(root, i),
            "attachments": atts,
            "comments": comments,
            "test_instances": tis,
            "created": created,
            "modified": created,
            "modified_by": user,
        }

    # -- what the site accepts --------------------------------------------------------------

    def utc_of(self, link) -> dict:
        m = UTC_LINK.match(str(link))
        if not m:
            raise FieldError("Invalid hyperlink - No URL match.")
        n = int(m.group(1))
        if not 1 <= n <= len(self.utcs):
            raise FieldError("Invalid hyperlink - Object does not exist.")
        return self.utcs[n - 1]

    def validate(self, data) -> tuple[dict | None, dict | None]:
        """(the instance's fields, None) or (None, a DRF-shaped 400 body)."""
        errors: dict[str, list[str]] = {}
        out: dict = {}

        def field(name, check, required=True, default=None):
            if name not in data:
                if required:
                    errors[name] = ["This field is required."]
                else:
                    out[name] = default
                return
            try:
                out[name] = check(data[name])
            except FieldError as exc:
                errors[name] = [exc.message]

        def tests(v):
            if not isinstance(v, dict):
                raise FieldError(f'Expected a dictionary of items but got type "{type(v).__name__}".')
            bad = [f'"{k}"' for k, t in v.items() if not isinstance(t, dict)]
            if bad:
                raise FieldError(f"{', '.join(bad)} field(s) have errors. Test data must be a dictionary ")
            return v

        def attachments(v):
            if not isinstance(v, list):
                raise FieldError(f'Expected a list of items but got type "{type(v).__name__}".')
            for a in v:
                if not isinstance(a, dict) or "filename" not in a or "value" not in a:
                    raise FieldError(ATTACHMENT_SHAPE)
                if a.get("encoding", "base64") == "base64" and not BASE64_RE.match(str(a["value"])):
                    raise FieldError("base64 encoding requested but content does not appear to be base64")
            return v

        def user_key(v):
            if v is None:
                return None
            v = str(v)
            if len(v) > 255:
                raise FieldError("Ensure this field has no more than 255 characters.")
            if any(i["user_key"] == v for i in self.instances):
                raise FieldError("test list instance with this user key already exists.")
            return v

        def flag(v):
            if isinstance(v, bool):
                return v
            if str(v).lower() in ("true", "1", "false", "0"):
                return str(v).lower() in ("true", "1")
            raise FieldError("Must be a valid boolean.")

        if not isinstance(data, dict):
            return None, {"non_field_errors": [f"Invalid data. Expected a dictionary, but got {type(data).__name__}."]}
        field("unit_test_collection", self.utc_of)
        field("work_started", lambda v: parse_work_time(v, self.zone))
        field(
            "work_completed", lambda v: parse_work_time(v, self.zone), required=False, default=_dt.datetime.now(_dt.UTC)
        )
        field("tests", tests)
        field("attachments", attachments, required=False, default=[])
        field("user_key", user_key, required=False)
        field("comment", lambda v: None if v is None else str(v), required=False)
        field("in_progress", flag, required=False, default=False)
        field("include_for_scheduling", flag, required=False, default=True)
        if errors:
            return None, errors
        macros = self.lists[out["unit_test_collection"]["test_list"]]
        given = out["tests"]
        missing = [m for m in macros if m not in given]
        wrong = [
            m
            for m in macros
            if m in given and not given[m].get("skipped") and not isinstance(given[m].get("value"), Number)
        ]
        msgs = []
        if missing:
            msgs.append(f"Missing data for tests: {', '.join(missing)}")
        if wrong:
            msgs.append(
                f"Wrong value type (number/string) for tests: {', '.join(wrong)}\nIf these are composite "
                "tests with missing dependencies, they should be marked as skipped in your request (e.g. "
                f"{{'tests': {{'{wrong[0]}': {{'skipped': True}}}}}})"
            )
        if out["work_completed"] < out["work_started"]:
            msgs.append("work_completed date must be after work_started")
        if msgs:
            return None, {"non_field_errors": ["\n".join(msgs)]}
        out["tests"] = {
            m: {
                "value": None if given[m].get("skipped") else given[m].get("value"),
                "skipped": bool(given[m].get("skipped", False)),
                "comment": str(given[m].get("comment") or ""),
            }
            for m in macros
        }
        return out, None

    def add(self, fields: dict, user: str, user_id: int) -> dict:
        """Store a validated instance; its record."""
        ti0 = 1 + sum(len(i["tests"]) for i in self.instances)
        atts = []
        for a in fields.get("attachments") or []:
            self.attachment_count += 1
            stem, dot, ext = str(a["filename"]).rpartition(".")
            stored = f"{stem or ext}_{_dt.date.today()}_{self.attachment_count:06x}{dot}{ext if stem else ''}"
            atts.append(
                {"id": self.attachment_count, "filename": a["filename"], "stored": stored, "size": len(a["value"])}
            )
        done = fields["work_completed"]
        if done == fields["work_started"]:  # as TestListInstance.save: an end equal to the start moves 60 s on
            done = done + _dt.timedelta(seconds=60)
        record = {
            "id": len(self.instances) + 1,
            "utc": fields["unit_test_collection"]["id"],
            "ti0": ti0,
            "work_started": fields["work_started"],
            "work_completed": done,
            "user_key": fields.get("user_key"),
            "comment": fields.get("comment"),
            "tests": fields["tests"],
            "in_progress": fields.get("in_progress", False),
            "include_for_scheduling": fields.get("include_for_scheduling", True),
            "attachments": atts,
            "created": _dt.datetime.now(_dt.UTC),
            "user": user,
            "user_id": user_id,
        }
        self.instances.append(record)
        return record
