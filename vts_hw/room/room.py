"""The room as one object: the rig's devices and files, each opened when first used and closed
with the room (issue 34 §1, docs/decisions/0099-the-room.md).

::

    with Room.open("rig.yaml") as room:          # a RigConfig or a path (None: $VTS_CONFIG, ./rig.yaml)
        cam = room.camera("cam1")                # one camera, or room.cameras: all of them
        room.trigger.fire()
        cal, mapping = room.calibration, room.mapping
        room.store.runs()

Nothing is opened by ``Room.open``: a part is opened when it is first asked for (a lazy
property), so `vts qa daily` never opens the trigger, and a rig with no calibration still
opens. ``close()`` closes what was opened, the last opened first; an error while closing one
part does not stop the others: the first is raised (the others added to it as notes), and
while another error is on its way out (``with`` ending in an exception) none is raised over it.
Errors name the file, key or device with the project's error classes (vts_hw/errors.py): a
calibration or mapping path that names no file is ConfigError (exit 2), a file that cannot be
read as one DataError (exit 3), a device that fails DeviceError (exit 4).

Procedures never hold the room: they are given its parts (the cameras, the trigger, the
calibration), as bluesky plans are given devices; the applications (the CLI, the console) and
the simulated scenarios open it.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vts_hw.camera import Camera
from vts_hw.config import RigConfig, load_rig
from vts_hw.drivers.registry import check_camera_kinds, open_camera, open_trigger
from vts_hw.drivers.trigger import TriggerGenerator
from vts_hw.errors import ConfigError
from vts_hw.lazy import load

if TYPE_CHECKING:
    from vts_hw.store import ResultsStore
    from vts_hw.store.paths import StoreTarget

__all__ = ["Room"]


# the one loaders of the calibration and the mapping (with OpenCV and SciPy behind them) and the
# store (SQLAlchemy) are loaded when first asked for: opening a room for the trigger loads none
def _read_calibration():
    return load("vts_hw.vision.calibration_io", "read_calibration")


def _read_mapping():
    return load("vts_hw.vision.registration", "read_mapping")


def _open_store(rig: RigConfig, target, mode: str) -> ResultsStore:
    if target is None:  # as every command resolves it: $VTS_STORE, rig.yaml's store:, the per-user file
        target = load("vts_hw.store.target", "resolve_target")(None, None, rig)
    return load("vts_hw.store", "ResultsStore")(target, mode=mode)


class Room:
    """The rig's cameras, trigger, calibration, VTS -> SPECT mapping and results store, each
    opened on first use. Make one with :meth:`open`.

    ``clock``: the host clock the devices stamp with (a simulated rig on virtual time passes
    its own, as ``open_camera(cfg, clock=...)`` takes it); ``store``: which store (a URL, a
    StoreTarget; default as every command resolves it: $VTS_STORE, rig.yaml's ``store:``, the
    per-user file) and ``store_mode`` (vts_hw.store.identity: ``read`` or ``create``);
    ``trigger_log``: the trigger.csv the trigger writes, when one is wanted."""

    def __init__(
        self,
        rig: RigConfig,
        *,
        clock: Callable[[], float] | None = None,
        store: str | os.PathLike | StoreTarget | None = None,
        store_mode: str = "create",
        trigger_log: str | Path | None = None,
    ):
        self.rig = rig
        self.clock = clock or time.time
        self._store_target = store
        self._store_mode = store_mode
        self._trigger_log = trigger_log
        self._cameras: dict[str, Camera] = {}
        self._parts: dict[str, Any] = {}
        self._opened: list[tuple[str, Any]] = []  # (what, the part: closed by its close()), in opening order
        self._closed = False

    @classmethod
    def open(cls, config: RigConfig | str | os.PathLike | None = None, **kw) -> Room:
        """The room of ``config`` (a RigConfig, or the path of a rig.yaml: ConfigError naming the
        file when it cannot be read as one). Nothing is opened yet."""
        rig = config if isinstance(config, RigConfig) else load_rig(config)
        return cls(rig, **kw)

    # ---- the parts ---------------------------------------------------------------------------

    def camera(self, name: str) -> Camera:
        """The camera ``name`` (ConfigError naming the known ones when there is none), opened once."""
        self._check_open()
        if name not in self._cameras:
            cfg = self.rig.camera(name)
            cam = open_camera(cfg, clock=self.clock)
            self._cameras[name] = cam
            self._opened.append((f"camera {name}", cam))
        return self._cameras[name]

    @property
    def cameras(self) -> list[Camera]:
        """Every camera of the rig, in rig.yaml's order; every kind is checked before any is
        opened, and one that cannot be opened leaves the others to :meth:`close`."""
        self._check_open()
        check_camera_kinds(self.rig.cameras)
        return [self.camera(c.name) for c in self.rig.cameras]

    @property
    def trigger(self) -> TriggerGenerator:
        """The trigger generator of rig.yaml's ``trigger:`` (ConfigError when it is ``none``)."""
        return self._part("trigger", lambda: open_trigger(self.rig, self._trigger_log, clock=self.clock))

    @property
    def calibration(self):
        """The camera calibration rig.yaml's ``calibration.cameras`` names, read by the one loader
        (a CameraCalibration, or named cameras for a plain list); None when none is named."""
        if self.rig.calibration.cameras is None:
            return None
        return self._part("calibration", lambda: _read_calibration()(self.calibration_file), closes=False)

    @property
    def calibration_file(self) -> Path | None:
        """The camera calibration file rig.yaml names (``calibration.cameras``; None when none),
        there as a file: ConfigError naming the key and the path when it is not (exit 2)."""
        path = self.rig.calibration.cameras
        return None if path is None else self._named_file(path, "calibration.cameras")

    @property
    def mapping(self):
        """The VTS -> SPECT mapping rig.yaml's ``calibration.mapping`` names (a RigidTransform);
        None when none is named."""
        path = self.rig.calibration.mapping
        if path is None:
            return None
        return self._part(
            "mapping", lambda: _read_mapping()(self._named_file(path, "calibration.mapping")), closes=False
        )

    @property
    def store(self) -> ResultsStore:
        """The results store (see the class), opened on first use."""
        return self._part("store", lambda: _open_store(self.rig, self._store_target, self._store_mode))

    def opened(self) -> list[str]:
        """What is open now, in opening order ("camera cam1", "trigger", "store", ...)."""
        return [what for what, _ in self._opened]

    # ---- closing -----------------------------------------------------------------------------

    def close(self) -> None:
        """Close every part that was opened, the last opened first; each is tried. The first
        error is raised once all were tried (the later ones added to it as notes)."""
        errors = self._close_all()
        if errors:
            first = errors[0]
            for other in errors[1:]:
                first.add_note(f"also while closing the room: {other}")
            raise first

    def __enter__(self) -> Room:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc is None:
            self.close()
            return
        for err in self._close_all():  # never over the error on its way out: said beside it
            exc.add_note(f"while closing the room after it: {err}")

    # ---- inside ------------------------------------------------------------------------------

    def _close_all(self) -> list[BaseException]:
        errors: list[BaseException] = []
        while self._opened:
            what, part = self._opened.pop()
            try:
                part.close()
            except Exception as exc:  # every part is closed, whatever one of them does
                errors.append(exc)
        self._cameras.clear()
        self._parts.clear()
        self._closed = True
        return errors

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("the room is closed")

    def _part(self, what: str, make: Callable[[], Any], closes: bool = True):
        self._check_open()
        if what not in self._parts:
            part = make()
            self._parts[what] = part
            if closes:
                self._opened.append((what, part))
        return self._parts[what]

    def _named_file(self, path: Path, key: str) -> Path:
        """A file rig.yaml names: ConfigError naming the file, the key and the path when it is not
        there (a setup mistake, exit 2); a file there that cannot be read is the loader's DataError."""
        if not Path(path).is_file():
            source = getattr(self.rig, "_source", None) or "rig.yaml"
            why = "is not a file" if Path(path).exists() else "does not exist"
            raise ConfigError(f"{source}: {key} names {path}, which {why}")
        return Path(path)
