"""What a request brings to the console, read strictly: the one door of every route's inputs.

A value a route cannot mean is a :class:`BadInput`: one sentence naming the parameter, key or
path part, and its HTTP status (400; 404 a path id that is not one; 413 a body too large; 414 a
query too long; 415 a body that is not JSON), answered by answers.py (HTML for a page, else JSON). Never a 500.

* **Every request** (:class:`StrictRequests`, ASGI middleware): each query parameter at most
  once (repeated: 400 naming it, never "the last one wins"), the query at most ``MAX_QUERY``
  characters, a declared body at most ``MAX_BODY`` bytes.
* **Query values** (:func:`query_text`, :func:`query_id`, :func:`query_page`): text of bounded
  length without control characters; whole numbers of ASCII digits within what the store
  holds (SQLite and PostgreSQL: 64-bit, ``INT_MAX``) and what the page can mean.
* **Path parts** (:func:`path_id`): ids the same way (a run, an artifact, an alert), any other
  text 404 (it names nothing there). Names (a camera, a report) are checked against what
  exists by the route (404 with a sentence).
* **JSON bodies** (:func:`json_body`): at most ``MAX_BODY`` bytes, sent as
  ``application/json``, UTF-8, no NaN/Infinity, no key twice, a JSON object, then the route's
  :class:`Body` model (pydantic): unknown keys named, types strict, numbers finite and within
  bounds, each key's sentence from its ``description``. No body, or ``{}``: the defaults.
docs/decisions/0080-console-inputs-and-audit.md.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from typing import Annotated, Any, TypeVar
from urllib.parse import parse_qsl

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError
from starlette.requests import Request

from vts_hw.console.answers import answer
from vts_hw.errors import UsageError

MAX_BODY = 16 * 1024  # the console's JSON bodies are some tens of bytes; the login form 8 KiB at most
MAX_QUERY = 4096
MAX_TEXT = 200  # a filter's text (a user name, a period)
INT_MAX = 2**63 - 1  # the largest integer SQLite and PostgreSQL (BIGINT) hold
_DIGITS = re.compile(r"[0-9]{1,19}")
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


class BadInput(UsageError):
    """An input a route cannot mean: one sentence naming it; ``status`` the HTTP status."""

    def __init__(self, sentence: str, status: int = 400):
        super().__init__(sentence)
        self.status = status


def shown(value, limit: int = 60) -> str:
    """``value`` as a sentence quotes it: its repr, cut to ``limit`` characters."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


# -- every request ------------------------------------------------------------------------------------


class StrictRequests:
    """The ASGI middleware of the module docstring (before any route reads the request)."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http":
            why = _refusal(scope)
            if why is not None:
                await answer(Request(scope), why.args[0], why.status)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _refusal(scope) -> BadInput | None:
    raw = scope.get("query_string", b"").decode("latin-1")
    if len(raw) > MAX_QUERY:
        return BadInput(f"the query is {len(raw)} characters long: the console reads at most {MAX_QUERY}", 414)
    counts = Counter(name for name, _ in parse_qsl(raw, keep_blank_values=True))
    for name, n in counts.items():
        if n > 1:
            return BadInput(f"the query parameter {shown(name)} is given {n} times: give it once")
    for key, value in scope.get("headers", ()):
        if key == b"content-length":
            if not value.isdigit():
                return BadInput("the request's Content-Length is not a number of bytes")
            if int(value) > MAX_BODY:
                return BadInput(
                    f"the request's body is {int(value)} bytes: the console takes at most {MAX_BODY} bytes", 413
                )
    return None


# -- query values and path parts --------------------------------------------------------------------------


def query_text(request: Request, name: str, default: str = "", limit: int = MAX_TEXT) -> str:
    """The query parameter ``name`` (stripped), ``default`` when absent; BadInput for one longer
    than ``limit`` characters or holding a control character."""
    value = request.query_params.get(name)
    if value is None:
        return default
    value = value.strip()
    if len(value) > limit:
        raise BadInput(f"the query parameter {name!r} is {len(value)} characters long: at most {limit}")
    if _CONTROL.search(value):
        raise BadInput(f"the query parameter {name!r} holds a control character: {shown(value)}")
    return value


def whole(text: str, what: str, low: int = 1, high: int = INT_MAX) -> int:
    """``text`` as a whole number from ``low`` to ``high`` (ASCII digits only); BadInput naming ``what``."""
    if not isinstance(text, str) or not _DIGITS.fullmatch(text) or not low <= int(text) <= high:
        raise BadInput(f"{what} {shown(text)} is not a whole number from {low} to {high}")
    return int(text)


def query_id(request: Request, name: str, what: str) -> int | None:
    """The id in query parameter ``name`` (None when absent or empty)."""
    text = query_text(request, name)
    return whole(text, what) if text else None


def query_page(request: Request, page_size: int, name: str = "page") -> int:
    """The page number in ``name`` (1 when absent): from 1 to the last page the store could hold."""
    text = query_text(request, name) or "1"
    last = INT_MAX // page_size
    if not _DIGITS.fullmatch(text) or not 1 <= int(text) <= last:
        raise BadInput(f"page {shown(text)} is not a page number (1, 2, ... at most {last})")
    return int(text)


def path_id(request: Request, name: str, what: str) -> int:
    """The id in path part ``name`` (a run, an artifact, an alert): 1 to ``INT_MAX``; any other
    text names nothing there: 404, saying what an id is."""
    text = str(request.path_params[name])
    if not _DIGITS.fullmatch(text) or not 1 <= int(text) <= INT_MAX:
        raise BadInput(f"no {what} {shown(text)}: {what} ids are whole numbers from 1 to {INT_MAX}", 404)
    return int(text)


# -- JSON bodies ----------------------------------------------------------------------------------------


class Body(BaseModel):
    """A route's JSON body: unknown keys refused, each field's ``description`` the sentence of
    what it must be ("a whole number from 1 to 50")."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class NoBody(Body):
    """The body of an action that takes nothing: none, or ``{}``."""


B = TypeVar("B", bound=Body)


def _not_bool(value):
    """A number of seconds as the pages send it: a JSON number, or the text of a form field
    ('' for none); a truth value is not one."""
    if isinstance(value, bool):
        raise ValueError("a truth value is not a number of seconds")
    if isinstance(value, str):
        value = value.strip()
        return float(value) if value else None  # ValueError for text that is not a number
    return value


#: a body's optional number of seconds (a JSON number or a form field's text; its bounds: seconds())
Seconds = Annotated[float | None, BeforeValidator(_not_bool)]


def seconds(high: float, description: str) -> Any:
    """The field of a :data:`Seconds`: finite, more than 0, at most ``high``, None when not given."""
    return Field(None, gt=0, le=high, allow_inf_nan=False, strict=False, description=description)


async def body_bytes(request: Request, limit: int = MAX_BODY) -> bytes:
    """The request's body, at most ``limit`` bytes (413 beyond, whatever the headers said)."""
    got = bytearray()
    async for chunk in request.stream():
        got += chunk
        if len(got) > limit:
            raise BadInput(f"the request's body is larger than {limit} bytes: the console takes at most {limit}", 413)
    return bytes(got)


def _no_constant(name: str):
    raise ValueError(f"{name} is not a JSON number")


def _no_twice(pairs):
    seen = {}
    for k, v in pairs:
        if k in seen:
            raise ValueError(f"the key {shown(k)} is given twice")
        seen[k] = v
    return seen


def _sentence(exc: ValidationError, model: type[Body]) -> str:
    err = exc.errors()[0]
    key = str(err["loc"][0]) if err["loc"] else ""
    fields = model.model_fields
    takes = f"it takes {', '.join(fields)}" if fields else "it takes none: send {} or no body"
    if err["type"] == "extra_forbidden":
        return f"the body's key {shown(key)} is not one this takes: {takes}"
    what = fields[key].description if key in fields and fields[key].description else "a valid value"
    if err["type"] == "missing":
        return f"the body needs {key!r}: {what}"
    return f"{key} must be {what}, not {shown(err.get('input'))}"


async def json_body(request: Request, model: type[B], example: str = "{}") -> B:
    """The request's JSON body as ``model`` (module docstring); BadInput with one sentence else.
    ``example``: a body this route takes, said when the body is not a JSON object."""
    raw = await body_bytes(request)
    data: object = {}
    if raw.strip():
        media = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if media != "application/json":
            raise BadInput(
                f"the body must be sent as JSON (Content-Type: application/json), not as {shown(media or 'no type')}",
                415,
            )
        try:
            data = json.loads(raw.decode("utf-8"), parse_constant=_no_constant, object_pairs_hook=_no_twice)
        except UnicodeDecodeError:
            raise BadInput(f"the body is not UTF-8 text: send a JSON object, e.g. {example}") from None
        except (ValueError, RecursionError) as exc:  # (a JSONDecodeError is a ValueError)
            why = exc.args[0] if isinstance(exc, ValueError) and exc.args else "nested too deep"
            raise BadInput(f"the body is not JSON ({str(why)[:80]}): send a JSON object, e.g. {example}") from None
    if not isinstance(data, dict):
        raise BadInput(f"the body must be a JSON object, e.g. {example}, not {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise BadInput(_sentence(exc, model)) from None


__all__ = [
    "BadInput",
    "StrictRequests",
    "Body",
    "NoBody",
    "Seconds",
    "seconds",
    "json_body",
    "body_bytes",
    "query_text",
    "query_id",
    "query_page",
    "path_id",
    "whole",
    "shown",
    "MAX_BODY",
    "MAX_QUERY",
    "INT_MAX",
]
