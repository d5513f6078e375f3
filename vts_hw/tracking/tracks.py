"""Marker tracks of a recording: positions (mm) over time with identities, and their files.

:class:`Tracks` is what :func:`vts_hw.tracking.processing.process_recording` returns; :meth:`Tracks.save`
and :meth:`Tracks.load` read and write the documented trajectory format
(docs/trajectory-format.md: a CSV of points and a JSON of the frames, cameras and metadata).
Clocks: ``host_time`` is the host's UTC epoch seconds as mapped from the cameras' stamps;
``spect_time``, when present, the SPECT's list-mode seconds. Units: mm, px, s.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vts_hw.bounded import SMALL, TABLE, open_bounded, read_text
from vts_hw.errors import DataError
from vts_hw.files import write_atomic, write_json_atomic
from vts_hw.spect.frame import SPECT_FRAME, VTS_AXES

__all__ = ["Tracks", "TRACKS_FORMAT"]

TRACKS_FORMAT = "vts-trajectory/1"


@dataclass(eq=False)
class Tracks:
    """Marker positions over time: the result of :func:`vts_hw.tracking.processing.process_recording`.

    C cameras (``camera_names``). Per *paired frame* (frame set) f (F of them, in time
    order): ``host_time[f]`` (host UTC epoch s, the mean of its cameras' mapped exposure
    times), ``camera_time[f, c]`` (camera c's own stamp, camera epoch s; NaN when camera c
    has no frame in the set), ``camera_frame[f, c]`` (frame number in camera c's index, -1
    when none), ``n_blobs[f, c]`` (markers detected, -1 when no frame), ``n_single[f, c]``
    (detections no other camera confirmed: markers seen by that camera only), optionally
    ``spect_time[f]`` (SPECT clock, s).
    Per *point* p (N): ``point_frame[p]`` (its paired frame), ``marker[p]`` (identity, from
    1), ``xyz[p]`` (mm, VTS frame), ``reproj_px[p]`` (RMS reprojection error, px),
    ``uv[p]`` (pixel centroids: camera 1 u, v, camera 2 u, v, ...; NaN for a camera the point
    was not seen by: ``point_cameras`` is its camera set), optionally ``xyz_spect[p]``
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
    n_single: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.host_time)

    @property
    def point_cameras(self) -> np.ndarray:
        """(N, C) bool: which cameras each point was triangulated from."""
        return ~np.isnan(self.uv[:, 0::2])

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

    def with_spect(self, mapping=None, host_to_spect: Callable | None = None) -> Tracks:
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
        return Tracks(
            self.host_time,
            list(self.camera_names),
            self.camera_time,
            self.camera_frame,
            self.n_blobs,
            self.point_frame,
            self.marker,
            self.xyz,
            self.reproj_px,
            self.uv,
            dict(self.unpaired),
            meta,
            xyz_spect,
            spect_time,
            self.n_single,
        )

    def marker_summary(self) -> list[dict]:
        """Per marker id: points, first and last host time (s), mean position and range of
        motion per axis (mm, VTS frame; ``*_spect`` too when present). The marker that
        moved most along an axis is the one to follow in a sync check."""
        out = []
        t = self.point_time
        for m in self.marker_ids():
            sel = self.marker == m
            d = {
                "marker": m,
                "points": int(sel.sum()),
                "first_time": float(t[sel].min()),
                "last_time": float(t[sel].max()),
                "mean_mm": self.xyz[sel].mean(axis=0).tolist(),
                "range_mm": np.ptp(self.xyz[sel], axis=0).tolist(),
            }
            if self.xyz_spect is not None:
                d["mean_spect_mm"] = self.xyz_spect[sel].mean(axis=0).tolist()
                d["range_spect_mm"] = np.ptp(self.xyz_spect[sel], axis=0).tolist()
            out.append(d)
        return out

    # -------------------------------------------------------------- files
    def _columns(self) -> list[str]:
        cols = ["frame", "host_time"]
        for c in self.camera_names:
            cols += [f"{c}_frame", f"{c}_time"]
        if self.spect_time is not None:
            cols.append("spect_time")
        cols += ["marker", "x_mm", "y_mm", "z_mm", "reproj_px"]
        for c in self.camera_names:
            cols += [f"{c}_u", f"{c}_v"]
        if self.xyz_spect is not None:
            cols += ["x_spect_mm", "y_spect_mm", "z_spect_mm"]
        return cols

    def save(self, path) -> tuple[Path, Path]:
        """Write ``<stem>.csv`` (a row per marker per paired frame) and ``<stem>.json``
        (metadata and the table of every paired frame). Returns both paths. A camera without
        a frame in a set, or not used for a point, leaves its cells empty."""
        path = Path(path)
        csv_path, json_path = path.with_suffix(".csv"), path.with_suffix(".json")
        pf = self.point_frame
        C = len(self.camera_names)
        ct = np.array(
            ["" if not np.isfinite(v) else f"{v:.2f}" for v in self.camera_time.ravel()], dtype=object
        ).reshape(-1, C)
        cf = np.array(["" if v < 0 else str(int(v)) for v in self.camera_frame.ravel()], dtype=object).reshape(-1, C)
        frame_txt = [
            f"{f},{self.host_time[f]:.6f}," + ",".join(f"{cf[f, c]},{ct[f, c]}" for c in range(C))
            for f in range(len(self.host_time))
        ]
        lines = [",".join(self._columns())]
        spect_time, xyz_spect = self.spect_time, self.xyz_spect

        def num(v):
            return "" if not np.isfinite(v) else f"{v:.4f}"

        for p in range(len(pf)):
            f = pf[p]
            row = frame_txt[f]
            if spect_time is not None:
                row += f",{spect_time[f]:.6f}"
            x, y, z = self.xyz[p]
            row += f",{self.marker[p]},{x:.4f},{y:.4f},{z:.4f},{self.reproj_px[p]:.4f}," + ",".join(
                num(v) for v in self.uv[p]
            )
            if xyz_spect is not None:
                xs, ys, zs = xyz_spect[p]
                row += f",{xs:.4f},{ys:.4f},{zs:.4f}"
            lines.append(row)
        write_atomic(csv_path, "\n".join(lines) + "\n", encoding="ascii")  # whole or not at all (disk full)

        def fin(a):
            return [None if not np.isfinite(v) else float(v) for v in a]

        frames: dict[str, list[float | None]] = {"host_time": [round(float(v), 6) for v in self.host_time]}
        for c, name in enumerate(self.camera_names):
            frames[f"{name}_frame"] = [None if v < 0 else int(v) for v in self.camera_frame[:, c]]
            frames[f"{name}_time"] = fin(self.camera_time[:, c])
        for c, name in enumerate(self.camera_names):
            frames[f"{name}_blobs"] = [None if v < 0 else int(v) for v in self.n_blobs[:, c]]
        if self.n_single is not None:
            for c, name in enumerate(self.camera_names):
                frames[f"{name}_single"] = self.n_single[:, c].tolist()
        if spect_time is not None:
            frames["spect_time"] = [round(float(v), 6) for v in spect_time]
        doc = {
            "format": TRACKS_FORMAT,
            "csv": csv_path.name,
            "cameras": list(self.camera_names),
            "units": {"position": "mm", "time": "s (UTC epoch)", "pixels": "px"},
            "clock": "host_time: host UTC epoch s, mapped from the camera stamps by the "
            "camera clock model; <camera>_time: that camera's own clock; "
            "spect_time: SPECT clock",
            "position_frame": f"x_mm..z_mm: {VTS_AXES}; x_spect_mm..: {SPECT_FRAME} "
            "(the volume: meta.spect_mapping.meta.spect_volume)",
            "meta": self.meta,
            "frames": frames,
            "unpaired": {k: [int(x) for x in v] for k, v in self.unpaired.items()},
        }
        write_json_atomic(json_path, doc)
        return csv_path, json_path

    @classmethod
    def load(cls, path) -> Tracks:
        """Read what :meth:`save` wrote (give the .csv, the .json or the common stem)."""
        path = Path(path)
        json_path, csv_path = path.with_suffix(".json"), path.with_suffix(".csv")
        try:
            doc = json.loads(read_text(json_path, SMALL, "trajectory metadata"))
        except (OSError, ValueError, RecursionError) as exc:
            raise DataError(
                f"{json_path}: cannot read the trajectory metadata ({str(exc)[:120] or 'nested too deeply'})"
            ) from None
        if not isinstance(doc, dict) or doc.get("format") != TRACKS_FORMAT:
            raise DataError(f"{json_path}: not a {TRACKS_FORMAT} file")
        try:
            return cls._from_files(doc, json_path, csv_path)
        except (KeyError, TypeError, ValueError, IndexError, OverflowError, AttributeError) as exc:
            raise DataError(
                f"{json_path} / {csv_path.name}: not a whole {TRACKS_FORMAT} trajectory "
                f"({type(exc).__name__}: {str(exc)[:80]})"
            ) from None

    @classmethod
    def _from_files(cls, doc: dict, json_path: Path, csv_path: Path) -> Tracks:
        names = [str(c) for c in doc["cameras"]]
        if len(names) < 2:
            raise ValueError("fewer than two cameras")
        C = len(names)
        fr = doc["frames"]

        def nanf(a):
            return np.array([np.nan if v is None else v for v in a], float)

        def intm(a):
            return np.array([-1 if v is None else v for v in a]).astype(int)

        host = np.array(fr["host_time"], float)
        camera_time = np.column_stack([nanf(fr[f"{c}_time"]) for c in names]).reshape(-1, C)
        camera_frame = np.column_stack([intm(fr[f"{c}_frame"]) for c in names]).reshape(-1, C)
        n_blobs = np.column_stack([intm(fr[f"{c}_blobs"]) for c in names]).reshape(-1, C)
        n_single = None
        if all(f"{c}_single" in fr for c in names):
            n_single = np.column_stack([intm(fr[f"{c}_single"]) for c in names]).reshape(-1, C)
        spect_time = np.array(fr["spect_time"], float) if "spect_time" in fr else None
        try:
            with open_bounded(csv_path, TABLE, "trajectory table", encoding="ascii") as f:
                header = f.readline().strip().split(",")
                body = f.read().strip()
        except OSError as exc:
            raise DataError(f"{csv_path}: cannot read the trajectory ({exc})") from None
        col = {name: i for i, name in enumerate(header)}
        for need in ("frame", "marker", "x_mm", "y_mm", "z_mm"):
            if need not in col:
                raise DataError(f"{csv_path}: no column {need!r}")
        rows = [r.split(",") for r in body.split("\n")] if body else []

        def get(name, typ=float):
            return np.array([typ(r[col[name]]) for r in rows], typ)

        def opt(name):
            return np.array([float(r[col[name]]) if r[col[name]] else np.nan for r in rows], float)

        xyz = np.column_stack([get("x_mm"), get("y_mm"), get("z_mm")]).reshape(-1, 3)
        uv = np.column_stack([opt(f"{c}_{a}") for c in names for a in "uv"]).reshape(-1, 2 * C)
        xyz_spect = None
        if "x_spect_mm" in col:
            xyz_spect = np.column_stack([get("x_spect_mm"), get("y_spect_mm"), get("z_spect_mm")]).reshape(-1, 3)
        unpaired = {k: np.array(v, int) for k, v in doc.get("unpaired", {}).items()}
        point_frame = get("frame", int)
        if len(point_frame) and not 0 <= point_frame.min() <= point_frame.max() < len(host):
            raise ValueError(f"a point's frame is not one of the {len(host)} frames of the .json")
        if not len(camera_time) == len(camera_frame) == len(n_blobs) == len(host):
            raise ValueError("the frame columns of the .json differ in length")
        return cls(
            host,
            names,
            camera_time,
            camera_frame,
            n_blobs,
            point_frame,
            get("marker", int),
            xyz,
            get("reproj_px"),
            uv,
            unpaired,
            doc.get("meta", {}),
            xyz_spect,
            spect_time,
            n_single,
        )
