"""Marker tracks of a recording: positions (mm) over time with identities, and their files.

:class:`Tracks` is what :func:`vts_hw.recording.processing.process_recording` returns; :meth:`Tracks.save`
and :meth:`Tracks.load` read and write the documented trajectory format
(docs/trajectory-format.md: a CSV of points and a JSON of the frames, cameras and metadata).
Clocks: ``host_time`` is the host's UTC epoch seconds as mapped from the cameras' stamps;
``spect_time``, when present, the SPECT's list-mode seconds. Units: mm, px, s.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from vts_hw.errors import DataError

__all__ = ["Tracks", "TRACKS_FORMAT"]

TRACKS_FORMAT = "vts-trajectory/1"


@dataclass(eq=False)
class Tracks:
    """Marker positions over time: the result of :func:`vts_hw.recording.processing.process_recording`.

    Per *paired frame* f (F of them, in time order): ``host_time[f]`` (host UTC epoch s, the
    mean of the two cameras' mapped exposure times), ``camera_time[f, c]`` (camera c's own
    stamp, camera epoch s), ``camera_frame[f, c]`` (frame number in camera c's index),
    ``n_blobs[f, c]`` (markers detected), optionally ``spect_time[f]`` (SPECT clock, s).
    Per *point* p (N): ``point_frame[p]`` (its paired frame), ``marker[p]`` (identity, from
    1), ``xyz[p]`` (mm, VTS frame), ``reproj_px[p]`` (RMS reprojection error, px),
    ``uv[p]`` (pixel centroids: camera 1 u, v, camera 2 u, v), optionally ``xyz_spect[p]``
    (mm, SPECT frame). ``unpaired``: per camera, frame numbers left without a partner.
    Files: :meth:`save` / :meth:`load`, format in docs/trajectory-format.md.
    """

    host_time: np.ndarray
    camera_names: list
    camera_time: np.ndarray
    camera_frame: np.ndarray
    n_blobs: np.ndarray
    point_frame: np.ndarray
    marker: np.ndarray
    xyz: np.ndarray
    reproj_px: np.ndarray
    uv: np.ndarray
    unpaired: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    xyz_spect: np.ndarray | None = None
    spect_time: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.host_time)

    @property
    def point_time(self) -> np.ndarray:
        """Host time (s) of every point."""
        return self.host_time[self.point_frame]

    def marker_ids(self) -> list[int]:
        return sorted(set(self.marker.tolist()))

    def trajectory(self, marker: int, frame: str = "vts") -> tuple[np.ndarray, np.ndarray]:
        """``(host_times, positions Nx3 mm)`` of one marker, in the VTS or SPECT frame."""
        sel = self.marker == marker
        xyz = self.xyz if frame == "vts" else self.xyz_spect
        if xyz is None:
            raise ValueError("these tracks have no SPECT-frame positions (see with_spect)")
        return self.point_time[sel], xyz[sel]

    def with_spect(self, mapping=None, host_to_spect: Callable | None = None) -> "Tracks":
        """A copy with SPECT-frame positions (``mapping.apply``: VTS → SPECT, e.g. the
        ``RigidTransform`` saved by the SPECT mapping procedure, read back with
        ``RigidTransform.load``, or an analysed ``SpectMapping``) and/or SPECT times
        (``host_to_spect``: host epoch s → SPECT clock s, applied to an array)."""
        meta = json.loads(json.dumps(self.meta))
        xyz_spect, spect_time = self.xyz_spect, self.spect_time
        if mapping is not None and not hasattr(mapping, "apply") and hasattr(mapping, "transform"):
            mapping = mapping.transform  # a SpectMapping after analyze()
        if mapping is not None:
            xyz_spect = np.asarray(mapping.apply(self.xyz), float).reshape(-1, 3)
            meta["spect_mapping"] = mapping.to_dict() if hasattr(mapping, "to_dict") else repr(mapping)
        if host_to_spect is not None:
            try:
                spect_time = np.asarray(host_to_spect(self.host_time), float).reshape(-1)
            except (TypeError, ValueError):
                spect_time = np.array([float(host_to_spect(float(t))) for t in self.host_time])
            meta["spect_time"] = getattr(host_to_spect, "__doc__", None) or "host_to_spect"
        return Tracks(self.host_time, list(self.camera_names), self.camera_time,
                      self.camera_frame, self.n_blobs, self.point_frame, self.marker, self.xyz,
                      self.reproj_px, self.uv, dict(self.unpaired), meta, xyz_spect, spect_time)

    def marker_summary(self) -> list[dict]:
        """Per marker id: points, first and last host time (s), mean position and range of
        motion per axis (mm, VTS frame; ``*_spect`` too when present). The marker that
        moved most along an axis is the one to follow in a sync check."""
        out = []
        t = self.point_time
        for m in self.marker_ids():
            sel = self.marker == m
            d = {"marker": m, "points": int(sel.sum()), "first_time": float(t[sel].min()),
                 "last_time": float(t[sel].max()),
                 "mean_mm": self.xyz[sel].mean(axis=0).tolist(),
                 "range_mm": np.ptp(self.xyz[sel], axis=0).tolist()}
            if self.xyz_spect is not None:
                d["mean_spect_mm"] = self.xyz_spect[sel].mean(axis=0).tolist()
                d["range_spect_mm"] = np.ptp(self.xyz_spect[sel], axis=0).tolist()
            out.append(d)
        return out

    # -------------------------------------------------------------- files
    def _columns(self) -> list[str]:
        c1, c2 = self.camera_names
        cols = ["frame", "host_time", f"{c1}_frame", f"{c1}_time", f"{c2}_frame", f"{c2}_time"]
        if self.spect_time is not None:
            cols.append("spect_time")
        cols += ["marker", "x_mm", "y_mm", "z_mm", "reproj_px",
                 f"{c1}_u", f"{c1}_v", f"{c2}_u", f"{c2}_v"]
        if self.xyz_spect is not None:
            cols += ["x_spect_mm", "y_spect_mm", "z_spect_mm"]
        return cols

    def save(self, path) -> tuple[Path, Path]:
        """Write ``<stem>.csv`` (a row per marker per paired frame) and ``<stem>.json``
        (metadata and the table of every paired frame). Returns both paths."""
        path = Path(path)
        csv_path, json_path = path.with_suffix(".csv"), path.with_suffix(".json")
        pf = self.point_frame
        ct = ["" if not np.isfinite(v) else f"{v:.2f}" for v in self.camera_time.ravel()]
        ct = np.array(ct, dtype=object).reshape(-1, 2)
        lines = [",".join(self._columns())]
        has_st, has_sp = self.spect_time is not None, self.xyz_spect is not None
        for p in range(len(pf)):
            f = pf[p]
            row = (f"{f},{self.host_time[f]:.6f},{self.camera_frame[f, 0]},{ct[f, 0]},"
                   f"{self.camera_frame[f, 1]},{ct[f, 1]}")
            if has_st:
                row += f",{self.spect_time[f]:.6f}"
            x, y, z = self.xyz[p]
            u1, v1, u2, v2 = self.uv[p]
            row += (f",{self.marker[p]},{x:.4f},{y:.4f},{z:.4f},{self.reproj_px[p]:.4f},"
                    f"{u1:.4f},{v1:.4f},{u2:.4f},{v2:.4f}")
            if has_sp:
                xs, ys, zs = self.xyz_spect[p]
                row += f",{xs:.4f},{ys:.4f},{zs:.4f}"
            lines.append(row)
        csv_path.write_text("\n".join(lines) + "\n", encoding="ascii")
        c1, c2 = self.camera_names
        fin = lambda a: [None if not np.isfinite(v) else float(v) for v in a]  # noqa: E731
        frames = {"host_time": [round(float(v), 6) for v in self.host_time],
                  f"{c1}_frame": self.camera_frame[:, 0].tolist(),
                  f"{c1}_time": fin(self.camera_time[:, 0]),
                  f"{c2}_frame": self.camera_frame[:, 1].tolist(),
                  f"{c2}_time": fin(self.camera_time[:, 1]),
                  f"{c1}_blobs": self.n_blobs[:, 0].tolist(),
                  f"{c2}_blobs": self.n_blobs[:, 1].tolist()}
        if has_st:
            frames["spect_time"] = [round(float(v), 6) for v in self.spect_time]
        doc = {"format": TRACKS_FORMAT, "csv": csv_path.name, "cameras": list(self.camera_names),
               "units": {"position": "mm", "time": "s (UTC epoch)", "pixels": "px"},
               "clock": "host_time: host UTC epoch s, mapped from the camera stamps by the "
                        "camera clock model; <camera>_time: that camera's own clock; "
                        "spect_time: SPECT clock",
               "position_frame": "x_mm..z_mm: VTS frame; x_spect_mm..: SPECT frame",
               "meta": self.meta, "frames": frames,
               "unpaired": {k: [int(x) for x in v] for k, v in self.unpaired.items()}}
        from vts_hw.files import write_json_atomic
        write_json_atomic(json_path, doc)
        return csv_path, json_path

    @classmethod
    def load(cls, path) -> "Tracks":
        """Read what :meth:`save` wrote (give the .csv, the .json or the common stem)."""
        path = Path(path)
        json_path, csv_path = path.with_suffix(".json"), path.with_suffix(".csv")
        try:
            doc = json.loads(json_path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError) as exc:
            raise DataError(f"{json_path}: cannot read the trajectory metadata "
                            f"({str(exc)[:120] or 'nested too deeply'})") from None
        if not isinstance(doc, dict) or doc.get("format") != TRACKS_FORMAT:
            raise DataError(f"{json_path}: not a {TRACKS_FORMAT} file")
        try:
            return cls._from_files(doc, json_path, csv_path)
        except (KeyError, TypeError, ValueError, IndexError, OverflowError, AttributeError) as exc:
            raise DataError(f"{json_path} / {csv_path.name}: not a whole {TRACKS_FORMAT} trajectory "
                            f"({type(exc).__name__}: {str(exc)[:80]})") from None

    @classmethod
    def _from_files(cls, doc: dict, json_path: Path, csv_path: Path) -> "Tracks":
        c1, c2 = doc["cameras"]
        fr = doc["frames"]
        nanf = lambda a: np.array([np.nan if v is None else v for v in a], float)  # noqa: E731
        host = np.array(fr["host_time"], float)
        camera_time = np.column_stack([nanf(fr[f"{c1}_time"]), nanf(fr[f"{c2}_time"])]).reshape(-1, 2)
        camera_frame = np.column_stack([fr[f"{c1}_frame"], fr[f"{c2}_frame"]]).astype(int).reshape(-1, 2)
        n_blobs = np.column_stack([fr[f"{c1}_blobs"], fr[f"{c2}_blobs"]]).astype(int).reshape(-1, 2)
        spect_time = np.array(fr["spect_time"], float) if "spect_time" in fr else None
        try:
            with open(csv_path, encoding="ascii") as f:
                header = f.readline().strip().split(",")
                body = f.read().strip()
        except OSError as exc:
            raise DataError(f"{csv_path}: cannot read the trajectory ({exc})") from None
        col = {name: i for i, name in enumerate(header)}
        for need in ("frame", "marker", "x_mm", "y_mm", "z_mm"):
            if need not in col:
                raise DataError(f"{csv_path}: no column {need!r}")
        rows = [r.split(",") for r in body.split("\n")] if body else []
        get = lambda name, typ=float: np.array([typ(r[col[name]]) for r in rows], typ)  # noqa: E731
        xyz = np.column_stack([get("x_mm"), get("y_mm"), get("z_mm")]).reshape(-1, 3)
        uv = np.column_stack([get(f"{c1}_u"), get(f"{c1}_v"), get(f"{c2}_u"),
                              get(f"{c2}_v")]).reshape(-1, 4)
        xyz_spect = None
        if "x_spect_mm" in col:
            xyz_spect = np.column_stack([get("x_spect_mm"), get("y_spect_mm"),
                                         get("z_spect_mm")]).reshape(-1, 3)
        unpaired = {k: np.array(v, int) for k, v in doc.get("unpaired", {}).items()}
        return cls(host, [c1, c2], camera_time, camera_frame, n_blobs, get("frame", int),
                   get("marker", int), xyz, get("reproj_px"), uv, unpaired, doc.get("meta", {}),
                   xyz_spect, spect_time)


