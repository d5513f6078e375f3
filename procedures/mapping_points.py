"""The VTS side of the VTS → SPECT mapping from a file: the phantom's sphere centres measured
by other means (`vts calibrate spect --vts FILE`), a CSV with a header x,y,z or a JSON list.
Light on purpose: `vts calibrate` imports it with its options (the cameras' side, in
procedures/mapping_inputs.py, brings the vision's numerics)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from vts_hw.bounded import SMALL, read_text
from vts_hw.errors import DataError


def read_points(path) -> np.ndarray:
    """Sphere centres (N×3, mm) from a CSV with a header x,y,z or a JSON list of [x, y, z].

    DataError for a missing or unreadable file, a missing column, a non-number or a row that
    is not three numbers.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such file.")
    try:
        text = read_text(path, SMALL, "points file", encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read the points ({exc}).") from None
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DataError(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno}).") from None
        except (ValueError, RecursionError) as exc:  # too deep, or a number of thousands of digits
            raise DataError(f"{path}: not usable JSON ({str(exc) or 'nested too deeply'}).") from None
        if isinstance(data, dict) and "points" in data:
            data = data["points"]
        if not isinstance(data, list) or not all(
            isinstance(p, list)
            and len(p) == 3
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in p)
            for p in data
        ):
            raise DataError(f"{path}: expected a JSON list of [x, y, z] points in mm.")
        try:
            pts = np.array(data, dtype=float).reshape(-1, 3)
        except OverflowError:
            raise DataError(f"{path}: a coordinate is too large to be a number of mm.") from None
    else:
        rows = [r for r in csv.reader(text.splitlines()) if any(c.strip() for c in r)]
        if not rows:
            raise DataError(f"{path}: empty; expected a CSV with a header x,y,z (mm).")
        header = [c.strip().lower() for c in rows[0]]
        missing = [k for k in ("x", "y", "z") if k not in header]
        if missing:
            raise DataError(
                f"{path}: the header {','.join(rows[0])!r} lacks column(s) {','.join(missing)}; expected x,y,z (mm)."
            )
        cols = [header.index(k) for k in ("x", "y", "z")]
        pts_list = []
        for n, row in enumerate(rows[1:], start=2):
            try:
                pts_list.append([float(row[c]) for c in cols])
            except (IndexError, ValueError):
                raise DataError(f"{path}, line {n}: {','.join(row)!r} is not three numbers x,y,z.") from None
        pts = np.array(pts_list, dtype=float).reshape(-1, 3)
    if len(pts) == 0:
        raise DataError(f"{path}: no points.")
    if not np.all(np.isfinite(pts)):
        raise DataError(f"{path}: non-finite coordinates.")
    return pts
