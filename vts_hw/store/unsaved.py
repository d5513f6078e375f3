"""Results that the store could not take: kept in a file until `vts qa import` puts them in.

When a run's figures cannot be written to the results store (disk full, read-only, a
database that is down), they are written as JSON to ``unsaved/`` next to an SQLite store's
file — else to the per-user data folder, the current folder, or the temporary folder, the
first that takes it. The file holds everything needed to store the run later with its own
times, states and tolerance windows (:func:`vts_hw.store.recorder.import_unsaved`); it is written
and read back by the one recorder (recorder.py), whatever the procedure.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
import socket
import tempfile
from pathlib import Path

from vts_hw.bounded import SMALL, read_text
from vts_hw.errors import DataError
from vts_hw.files import PRIVATE, WriteFailed, write_json_atomic
from vts_hw.store.paths import default_path, sqlite_file, to_url

FORMAT = "vts-unsaved-run/1"


def candidate_folders(url: str | None) -> list[Path]:
    """Where an unsaved run may go, best first."""
    out = []
    try:
        db = sqlite_file(to_url(url))
    except Exception:  # a URL that does not parse: the other places still work
        db = None
    if db is not None:
        out.append(db.parent / "unsaved")
    out += [default_path().parent / "unsaved", Path.cwd(), Path(tempfile.gettempdir())]
    return out


def save_unsaved(url: str | None, run: dict) -> tuple[Path | None, list[str]]:
    """Write ``run`` (see :func:`vts_hw.store.recorder.import_unsaved` for its keys) to the first place that takes
    it; return the path (None if none did) and why the places before it failed."""
    stamp = _dt.datetime.fromtimestamp(run.get("started") or 0, _dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    name = f"{run.get('procedure', 'run')}-{stamp}-{socket.gethostname()}-{os.getpid()}.json"
    doc = {"format": FORMAT, **run}
    tried: list[str] = []
    for folder in candidate_folders(url):
        made = not folder.exists()
        try:
            folder.mkdir(parents=True, exist_ok=True, mode=0o700)
            # owner-only, as the store it waits for (decision 0081): $TMPDIR is everyone's
            return write_json_atomic(folder / name, doc, mode=PRIVATE), tried
        except (OSError, WriteFailed) as exc:
            tried.append(f"{folder}: {exc}")
            if made:  # an empty unsaved/ made here would look like a place runs wait in
                with contextlib.suppress(OSError):
                    folder.rmdir()
    return None, tried


def load_unsaved(path: str | Path) -> dict:
    p = Path(path)
    try:
        doc = json.loads(read_text(p, SMALL, "unsaved QA run"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DataError(f"{p}: cannot read the unsaved run ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or not isinstance(doc.get("measurements"), list):
        raise DataError(f"{p}: not an unsaved run written by vts (format {FORMAT})")
    return doc
