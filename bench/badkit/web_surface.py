"""The console's surface, read from its code (the class "web" of bench/bad_inputs.py, issue 32 §5):
every route and method of the Starlette application ``create_app`` builds (with users and without),
and every slot a request fills: the route's path parameters, and the query parameters, JSON body
keys and form fields its handler reads. Those are found in the handler's source and in the sources
of the functions it calls (followed through its closure, its module and ``self``, three calls deep):
a ``.get("k")``, ``.getlist("k")`` or ``["k"]`` on ``request.query_params`` (or a ``params``
mapping it was handed), on a JSON body (``json_object(...)``, a name ``body``) or on a ``form``;
and the fields of any pydantic model a handler validates a body with. Nothing here is a list of
the console's routes or names: a new route, parameter or key is swept without being named.
"""

from __future__ import annotations

import ast
import inspect
import textwrap
from dataclasses import dataclass, field

from starlette.convertors import IntegerConvertor, PathConvertor
from starlette.routing import Mount, Route

QUERY_RECEIVERS = {"params", "query", "query_params", "qs"}
BODY_RECEIVERS = {"body", "data", "payload", "asked"}
FORM_RECEIVERS = {"form", "fields"}
BODY_READERS = (
    "json_object",
    "json_body",
    "body_bytes",
    ".json(",
    ".body(",
    ".form(",
    "switch_asked",
    "_form(",
    "model_validate",
)


@dataclass
class Endpoint:
    """One route and method: its path template, its path parameters (name -> 'int', 'path' or
    'str'), the query, body and form keys its handler reads, whether it reads a body at all."""

    path: str
    method: str
    params: dict[str, str]
    query: list[str] = field(default_factory=list)
    body: list[str] = field(default_factory=list)
    form: list[str] = field(default_factory=list)
    reads_body: bool = False
    stream: bool = False  # an event stream (text/event-stream): read its start only

    @property
    def name(self) -> str:
        return f"{self.method} {self.path}"


def _kind(conv) -> str:
    return "int" if isinstance(conv, IntegerConvertor) else "path" if isinstance(conv, PathConvertor) else "str"


def _source(fn) -> ast.AST | None:
    try:
        return ast.parse(textwrap.dedent(inspect.getsource(fn)))
    except (OSError, TypeError, SyntaxError):
        return None


def _reached(fn, depth: int = 3, seen=None) -> list:
    """``fn`` and the functions of vts_hw it calls (through its closure, globals and ``self``)."""
    seen = set() if seen is None else seen
    fn = inspect.unwrap(fn)
    key = getattr(fn, "__func__", fn)
    if key in seen or not callable(fn):
        return []
    seen.add(key)
    out = [fn]
    if depth == 0:
        return out
    tree = _source(fn)
    if tree is None:
        return out
    try:
        cv = inspect.getclosurevars(getattr(fn, "__func__", fn))
        names = {**cv.globals, **cv.nonlocals}
    except (TypeError, ValueError):
        names = {}
    owner = getattr(fn, "__self__", None)
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        target = None
        if isinstance(node.func, ast.Name):
            target = names.get(node.func.id)
        elif isinstance(node.func, ast.Attribute) and isinstance(node.func.value, ast.Name):
            if node.func.value.id == "self" and owner is not None:
                target = getattr(owner, node.func.attr, None)
            elif node.func.value.id in names and inspect.ismodule(names[node.func.value.id]):
                target = getattr(names[node.func.value.id], node.func.attr, None)
        if (
            target is not None
            and (inspect.isfunction(target) or inspect.ismethod(target))
            and getattr(target, "__module__", "").startswith("vts_hw")
        ):
            out += _reached(target, depth - 1, seen)
    return out


def _receiver(node: ast.AST) -> str:
    return ast.unparse(node)


def _fn_node(tree: ast.AST):
    return next((n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))), None)


def _tuple_strings(tree: ast.AST) -> list[str]:
    """The strings of every tuple or list literal of strings in ``tree`` (the keys a loop reads)."""
    out = []
    for n in ast.walk(tree):
        if (
            isinstance(n, (ast.Tuple, ast.List))
            and n.elts
            and all(isinstance(e, ast.Constant) and isinstance(e.value, str) for e in n.elts)
        ):
            out += [e.value for e in n.elts]
    return out


def _query_readers(fns) -> dict[str, tuple[str, int, object]]:
    """The helpers among ``fns`` that read the query parameter a parameter of theirs names
    (``query_params.get(name)``): {function name: (that parameter, its position, its default)}."""
    out = {}
    for fn in fns:
        tree = _source(fn)
        node = _fn_node(tree) if tree is not None else None
        if node is None:
            continue
        params = [a.arg for a in node.args.args]
        defaults = dict(zip(params[len(params) - len(node.args.defaults) :], node.args.defaults))
        for n in ast.walk(node):
            if (
                isinstance(n, ast.Call)
                and isinstance(n.func, ast.Attribute)
                and n.func.attr in ("get", "getlist")
                and "query_params" in ast.unparse(n.func.value)
                and n.args
                and isinstance(n.args[0], ast.Name)
                and n.args[0].id in params
            ):
                name = n.args[0].id
                d = defaults.get(name)
                out[node.name] = (name, params.index(name), d.value if isinstance(d, ast.Constant) else None)
    # a helper handing a parameter of its own to a reader as the name it reads is one too (query_id)
    changed = True
    while changed:
        changed = False
        for fn in fns:
            tree = _source(fn)
            node = _fn_node(tree) if tree is not None else None
            if node is None or node.name in out:
                continue
            params = [a.arg for a in node.args.args]
            defaults = dict(zip(params[len(params) - len(node.args.defaults) :], node.args.defaults))
            for n in ast.walk(node):
                callee = n.func.id if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) else ""
                if callee in out and callee != node.name:
                    pname, pos, _ = out[callee]
                    given = next(
                        (k.value for k in n.keywords if k.arg == pname), n.args[pos] if len(n.args) > pos else None
                    )
                    if isinstance(given, ast.Name) and given.id in params:
                        d = defaults.get(given.id)
                        out[node.name] = (
                            given.id,
                            params.index(given.id),
                            d.value if isinstance(d, ast.Constant) else None,
                        )
                        changed = True
                        break
    return out


def _models(fn) -> list:
    """The pydantic models a function names (a body validated as one: its fields are body keys)."""
    try:
        cv = inspect.getclosurevars(getattr(fn, "__func__", fn))
    except (TypeError, ValueError):
        return []
    return [
        v
        for v in {**cv.globals, **cv.nonlocals}.values()
        if inspect.isclass(v) and isinstance(getattr(v, "model_fields", None), dict)
    ]


def _keys(fns) -> tuple[list[str], list[str], list[str], bool, bool]:
    """(query keys, body keys, form keys, reads a body, answers an event stream) of these functions."""
    query, body, form = [], [], []
    reads, stream = False, False
    readers = _query_readers(fns)
    for fn in fns:
        tree = _source(fn)
        if tree is None:
            continue
        for m in _models(fn):  # a body read as a model: its fields
            body += list(m.model_fields)
        for n in ast.walk(tree):  # a helper reading the query parameter it is named
            if not isinstance(n, ast.Call):
                continue
            callee = (
                n.func.id if isinstance(n.func, ast.Name) else n.func.attr if isinstance(n.func, ast.Attribute) else ""
            )
            if callee not in readers:
                continue
            pname, pos, default = readers[callee]
            given = next((k.value for k in n.keywords if k.arg == pname), n.args[pos] if len(n.args) > pos else None)
            if given is None:
                query += [default] if isinstance(default, str) else []
            elif isinstance(given, ast.Constant) and isinstance(given.value, str):
                query.append(given.value)
            else:  # a key from a loop: the keys of the tuples it loops over
                query += _tuple_strings(tree)
        text = ast.unparse(tree)
        reads = reads or any(r in text for r in BODY_READERS)
        stream = stream or "event_stream(" in text or "text/event-stream" in text
        for node in ast.walk(tree):
            key, recv = None, None
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr in ("get", "getlist", "pop")
                and node.args
                and isinstance(node.args[0], ast.Constant)
                and isinstance(node.args[0].value, str)
            ):
                key, recv = node.args[0].value, node.func.value
            elif (
                isinstance(node, ast.Subscript)
                and isinstance(node.slice, ast.Constant)
                and isinstance(node.slice.value, str)
            ):
                key, recv = node.slice.value, node.value
            if key is None:
                continue
            r = _receiver(recv)
            last = r.rsplit(".", 1)[-1]
            if "query_params" in r or last in QUERY_RECEIVERS:
                query.append(key)
            elif "query_params" in r:
                pass
            elif "json_object" in r or ".json(" in r or last in BODY_RECEIVERS:
                body.append(key)
            elif last in FORM_RECEIVERS:
                form.append(key)
        for n in ast.walk(tree):  # query_params.get(k), k from a loop over a tuple
            if (
                isinstance(n, ast.Call)
                and isinstance(n.func, ast.Attribute)
                and n.func.attr in ("get", "getlist")
                and "query_params" in ast.unparse(n.func.value)
                and n.args
                and isinstance(n.args[0], ast.Name)
                and fn.__name__ not in readers
            ):
                query += _tuple_strings(tree)
        # a pydantic model a handler validates its body with: its fields are body keys
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and node.attr in ("model_validate", "model_validate_json")
                and isinstance(node.value, ast.Name)
            ):
                model = getattr(inspect.getmodule(fn), node.value.id, None)
                body += list(getattr(model, "model_fields", {}) or {})
    uniq = lambda xs: list(dict.fromkeys(xs))  # noqa: E731
    return uniq(query), uniq(body), uniq(form), reads, stream


def endpoints(app) -> list[Endpoint]:
    """Every route and method of ``app`` (HEAD left out: GET's), with its slots; a Mount (the
    static files) as one GET endpoint with its path parameter."""
    out = []
    for r in app.routes:
        params = {k: _kind(c) for k, c in getattr(r, "param_convertors", {}).items()}
        if isinstance(r, Mount):
            out.append(Endpoint(r.path + "/{path:path}", "GET", params))
            continue
        if not isinstance(r, Route):
            continue
        q, b, f, reads, stream = _keys(_reached(r.endpoint))
        for m in sorted((r.methods or {"GET"}) - {"HEAD"}):
            out.append(
                Endpoint(
                    r.path,
                    m,
                    params,
                    q,
                    b if m != "GET" else [],
                    f if m != "GET" else [],
                    reads and m != "GET",
                    stream and m == "GET",
                )
            )
    return out


def console_apps():
    """The console's application without users and with (the routes differ: login, logout);
    built on a Console with no rig, as the pages' code builds its routes without one."""
    from vts_hw.console.app import Console, create_app
    from vts_hw.console.sessions import Auth

    return {
        "no users": create_app(Console("sweep", None, None, None)),
        "users": create_app(Console("sweep", None, None, None, auth=Auth(required=True, load_users=list))),
    }


def surface() -> dict[str, list[Endpoint]]:
    return {k: endpoints(app) for k, app in console_apps().items()}


if __name__ == "__main__":  # what the sweep will walk
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    for kind, eps in surface().items():
        print(f"-- {kind}: {len(eps)} endpoints")
        for e in eps:
            print(
                f"  {e.name:<40} path={e.params} query={e.query} body={e.body} form={e.form}"
                f"{' reads a body' if e.reads_body else ''}{' stream' if e.stream else ''}"
            )
