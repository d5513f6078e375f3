"""What a simulated Axis camera is: its model profile (YAML package data) and parameter tree.

A profile is one YAML file beside this module (:data:`MODELS`), chosen by the camera's
``model`` argument (``SimAxisCamera(source, model="axis211")``), the way QCoDeS picks a
simulated instrument from a YAML file. It names the firmware generation and everything that
follows from it: the VAPIX version, the CGIs that exist (every other ``/axis-cgi/`` path is a
404, as on the real firmware), the APIs ``apidiscovery.cgi`` lists, whether the connection is
closed after each response, the layout of the Axis JPEG comment segments, and the parameter
tree, written as the ``root.``-less lines of a ``param.cgi?action=list`` dump. Placeholders in
braces are filled per camera: ``{serial}``, ``{mac}``, ``{name}``, ``{resolution}``,
``{resolutions}``, ``{firmware}``, ``{hardware_id}``, ``{fps}``, ``{compression}``.

:class:`ParamStore` holds one camera's tree in memory and answers ``action=list`` and
``action=update`` as the firmware does (``Brand`` and ``Properties`` read-only, a few values
checked, all-or-nothing updates).
"""

from __future__ import annotations

import re
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from typing import Any

import yaml

from vts_hw.recording.axis_jpeg import AxisProduct

DEFAULT_FPS = 25
MAX_FPS = 30
DEFAULT_COMPRESSION = 25
DEFAULT_MODEL = "p1375"
MODELS = {
    "p1375": "axis_p1375.yaml",  # AXIS P1375, AXIS OS 10.12: current firmware
    "axis211": "axis_211.yaml",
}  # AXIS 211, firmware 4.47: the reference system's camera
LEGACY_ALIASES = {"vapix3": DEFAULT_MODEL, "vapix2": "axis211"}  # the former firmware= names
JPEG_LAYOUTS = ("after_app0", "after_tables")

_PLACEHOLDER = re.compile(r"\{(serial|mac|name|resolution|resolutions|firmware|hardware_id|fps|compression)\}")


@dataclass(frozen=True)
class Profile:
    """One camera model on one firmware generation (read from its YAML file)."""

    model: str
    """The profile's name (``p1375``, ``axis211``)."""
    vapix: int
    firmware: tuple[int, int, int]
    """Properties.Firmware.Version and the firmware bytes of the JPEG product segment."""
    firmware_str: str
    hardware_id: int
    oui: bytes | None
    """First three MAC bytes of this product line (None: keep the source's MAC)."""
    jpeg_layout: str
    """``after_app0``: time then product after the JFIF header (firmware 5 and later);
    ``after_tables``: product then time after the quantisation tables (firmware 4.x)."""
    time_extra_zero: bool
    """Firmware 4.x leaves the 5 spare bytes of the time segment zero; later ones repeat the time."""
    close_after_response: bool
    """Old web servers answer HTTP/1.0 and close the connection after every response."""
    cgis: frozenset[str]
    apis: tuple[dict[str, str], ...]
    params_text: str
    exposure_ms: float = 8.0
    """How long the sensor exposes each frame (the simulated image's motion blur)."""

    @classmethod
    def load(cls, model: str) -> Profile:
        model = LEGACY_ALIASES.get(model, model)
        if model not in MODELS:
            raise ValueError(f"no simulated Axis model {model!r}; known: {', '.join(MODELS)}")
        data = yaml.safe_load(resources.files(__package__).joinpath(MODELS[model]).read_text("utf-8"))
        fw = tuple(int(x) for x in str(data["firmware"]).split("."))
        if len(fw) != 3 or not all(0 <= x <= 255 for x in fw):
            raise ValueError(f"{MODELS[model]}: firmware must be three numbers 0-255, not {data['firmware']}")
        if data["jpeg_layout"] not in JPEG_LAYOUTS:
            raise ValueError(f"{MODELS[model]}: jpeg_layout must be one of {JPEG_LAYOUTS}")
        oui = data.get("oui")
        return cls(
            model=model,
            vapix=int(data["vapix"]),
            firmware=fw,
            firmware_str=str(data.get("firmware_version", data["firmware"])),
            hardware_id=int(data["hardware_id"]),
            oui=bytes.fromhex(oui) if oui else None,
            jpeg_layout=data["jpeg_layout"],
            time_extra_zero=bool(data.get("time_extra_zero", False)),
            close_after_response=bool(data.get("close_after_response", False)),
            cgis=frozenset(data["cgis"]),
            apis=tuple(data.get("apis") or ()),
            params_text=data["params"],
            exposure_ms=float(data.get("exposure_ms", 8.0)),
        )

    def product(self, source_product: AxisProduct) -> AxisProduct:
        """The product segment this camera writes: this model's hardware id and firmware, the
        source's MAC (with this product line's OUI where the profile names one)."""
        mac = source_product.mac if self.oui is None else self.oui + source_product.mac[3:]
        return AxisProduct(self.hardware_id, self.firmware, mac)

    def params(self, product: AxisProduct, name: str, resolutions: list[str]) -> dict[str, str]:
        """The parameter tree (``root.X=Y``) with this camera's values filled in."""
        values = {
            "serial": product.mac.hex().upper(),
            "mac": product.mac_str,
            "name": name,
            "resolution": resolutions[0],
            "resolutions": ",".join(resolutions),
            "firmware": self.firmware_str,
            "hardware_id": format(product.hardware_id, "X"),
            "fps": str(DEFAULT_FPS),
            "compression": str(DEFAULT_COMPRESSION),
        }
        tree: dict[str, str] = {}
        for line in self.params_text.splitlines():
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            key, sep, value = line.partition("=")
            if not sep:
                raise ValueError(f"{MODELS[self.model]}: parameter line without '=': {line!r}")
            tree["root." + key.strip()] = _PLACEHOLDER.sub(lambda m: values[m.group(1)], value)
        return tree


class ParamStore:
    """The camera's parameter tree (``root.X.Y=Z``), in memory, safe between threads."""

    READ_ONLY = ("root.Brand.", "root.Properties.", "root.Network.eth0.MACAddress")

    def __init__(self, values: dict[str, str], resolutions: list[str]):
        self._values = dict(values)
        self._resolutions = resolutions
        self._lock = threading.Lock()

    @staticmethod
    def _full(name: str) -> str:
        name = name.strip()
        return name if name.startswith("root.") or name == "root" else "root." + name

    def get(self, name: str) -> str:
        with self._lock:
            return self._values[self._full(name)]

    def find(self, name: str) -> str | None:
        with self._lock:
            return self._values.get(self._full(name))

    def list(self, groups: str | None) -> str:
        """The body of ``action=list``: matching lines, and an error line per unknown group."""
        names = [g for g in (groups or "root").split(",") if g.strip()] or ["root"]
        out: list[str] = []
        with self._lock:
            for group in names:
                full = self._full(group)
                hits = [k for k in self._values if k == full or k.startswith(full + ".") or full == "root"]
                if hits:
                    out += [f"{k}={self._values[k]}" for k in hits]
                else:
                    out.append(f"# Error: Error -1 getting param in group '{group.strip()}'")
        return "".join(line + "\r\n" for line in out)

    def update(self, changes: Sequence[tuple[str, str]]) -> str:
        """The body of ``action=update``: ``OK`` or the first error; nothing changes on error."""
        checked: list[tuple[str, str]] = []
        with self._lock:
            for name, value in changes:
                full = self._full(name)
                if full not in self._values or full.startswith(self.READ_ONLY) or not self._valid(full, value):
                    return f"# Error: Error setting '{full}' to '{value}'!\r\n"
                checked.append((full, value))
            self._values.update(checked)
        return "OK\r\n"

    def _valid(self, full: str, value: str) -> bool:
        if full.endswith(".Appearance.Resolution"):
            return value in self._resolutions
        return valid_value(full, value)


def _whole(low: int, high: int):
    return lambda v: v.isdigit() and low <= int(v) <= high


_YES_NO = ("yes", "no")
_TZ_POSIX = re.compile(r"^[A-Za-z]{3,}[-+]?\d{1,2}(:\d{2})?([A-Za-z]{3,}([-+]?\d{1,2})?(,[-A-Za-z0-9.:/]+){0,2})?$")
_HOST = re.compile(r"^(?=.{1,253}$)[A-Za-z0-9]([A-Za-z0-9-]{0,62})(\.[A-Za-z0-9]([A-Za-z0-9-]{0,62}))*$")
#: what the firmware takes for a parameter (by the end of its name): a test of the value. A
#: parameter not named here takes any text, as free-text parameters (names, descriptions) do.
RULES = {
    ".Appearance.Compression": _whole(0, 100),
    ".Stream.FPS": _whole(0, MAX_FPS),  # 0: as fast as the camera can
    ".Sensor.Exposure": lambda v: v in ("auto", "hold", "flickerfree50", "flickerfree60"),
    ".Sensor.WhiteBalance": lambda v: (
        v in ("auto", "hold", "fixed_indoor", "fixed_outdoor1", "fixed_outdoor2", "fixed_fluor1", "fixed_fluor2")
    ),
    ".Sensor.ExposureValue": _whole(0, 100),
    ".Sensor.ExposurePriority": _whole(0, 100),
    ".Sensor.MaxExposureTime": _whole(100, 1_000_000),  # microseconds
    ".Sensor.MaxGain": _whole(0, 48),  # dB
    ".Text.TextEnabled": lambda v: v in _YES_NO,
    ".Text.ClockEnabled": lambda v: v in _YES_NO,
    ".Text.DateEnabled": lambda v: v in _YES_NO,
    ".Overlay.Enabled": lambda v: v in _YES_NO,
    ".DST.Enabled": lambda v: v in _YES_NO,
    ".ObtainFromDHCP": lambda v: v in _YES_NO,
    "root.Time.SyncSource": lambda v: v in ("NTP", "None", "PC"),
    "root.Time.NTP.Server": lambda v: v == "" or bool(_HOST.match(v)),
    "root.Time.POSIXTimeZone": lambda v: bool(_TZ_POSIX.match(v)),
    "root.Time.TimeZone": lambda v: valid_time_zone(v),
}


def valid_time_zone(value: str) -> bool:
    """An IANA time zone name (current firmware) or a POSIX TZ string such as ``UTC0`` or
    ``CET-1CEST,M3.5.0,M10.5.0/3`` (firmware 4.x names its zone that way)."""
    import zoneinfo

    if _TZ_POSIX.match(value) or value in ("GMT", "UTC"):
        return True
    try:
        return "/" in value and zoneinfo.ZoneInfo(value) is not None
    except (zoneinfo.ZoneInfoNotFoundError, ValueError):
        return False


def valid_value(full: str, value: str) -> bool:
    """Whether the firmware takes ``value`` for parameter ``full`` (``root.`` name)."""
    for suffix, check in RULES.items():
        if full == suffix or (suffix.startswith(".") and full.endswith(suffix)):
            return bool(check(value))
    return "\n" not in value and "\r" not in value


def describe(profile: Profile) -> dict[str, Any]:
    """The profile in a few words (for ``/sim/state`` and logs)."""
    return {"model": profile.model, "vapix": profile.vapix, "firmware_version": profile.firmware_str}
