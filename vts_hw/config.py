"""rig.yaml: the room, validated at load.

Every error names the file, the key (dotted path) and what was expected, in one sentence.
Passwords never live in the file: a camera names the environment variable that holds its
password (``password_env``).
"""

from __future__ import annotations

import hashlib
import os
import re
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, field_validator, model_validator
from pydantic_core import ErrorDetails

from vts_hw.bounded import ANY_SIZE, TooLarge, open_checked, read_bytes
from vts_hw.catalog import windows as default_windows
from vts_hw.config_base import Strict as _Strict
from vts_hw.config_qatrack import QATrackConfig
from vts_hw.config_setup import CameraSetupConfig
from vts_hw.config_warmup import WarmupSettings
from vts_hw.errors import ConfigError
from vts_hw.vision.aim_settings import AimSettings

ENV_CONFIG = "VTS_CONFIG"
_NAME_RE = r"^[A-Za-z0-9][A-Za-z0-9_.-]*$"
# a camera's host as it goes into its URLs: a name or an IPv4 address, or an IPv6 one in brackets
_HOST_RE = re.compile(r"[A-Za-z0-9_]([A-Za-z0-9_.-]*[A-Za-z0-9_])?|\[[0-9A-Fa-f:.]+\]")


class CameraConfig(_Strict):
    """One camera: an Axis camera by default, or another ``kind`` (drivers/registry.py)."""

    name: str = Field(pattern=_NAME_RE, description="short name used on the command line and in files")
    kind: str = Field(
        default="axis",
        pattern=r"^[a-z][a-z0-9_]*$",
        description="which driver: axis (the default), mjpeg, replay (drivers/registry.py)",
    )
    options: dict[str, Any] = Field(
        default_factory=dict,
        description="settings of the kind, checked by its driver (e.g. replay: folder, camera, speed)",
    )
    host: str | None = Field(default=None, min_length=1, description="network cameras: address")
    port: int = Field(default=80, ge=1, le=65535)
    scheme: Literal["http", "https"] = "http"
    user: str = "root"
    password_env: str | None = Field(
        default=None,
        pattern=r"^[A-Za-z_][A-Za-z0-9_]*$",
        description="name of the environment variable holding the password",
    )
    led_port: int = Field(default=1, ge=1, le=8, description="I/O output port of the LED ring, 1-based")
    resolution: tuple[int, int] = (640, 480)
    fps: float = Field(default=25.0, gt=0, le=60)
    compression: int = Field(
        default=25, ge=0, le=100, description="Axis compression; JPEG quality is 100 - compression"
    )
    timeout_s: float = Field(default=5.0, gt=0, le=120)
    wall_mm_per_px: float = Field(default=1.25, gt=0, le=100, description="scale at the wall markers, for drift in mm")
    locked_params: dict[str, str | int | float] = Field(
        default_factory=dict, description="further VAPIX parameters the daily QA checks, e.g. exposure"
    )
    ca_cert: Path | None = Field(
        default=None, description="https: a PEM certificate to trust for this camera (e.g. its self-signed one)"
    )
    warmup_min: float = Field(
        default=30.0,
        ge=0,
        le=24 * 60,
        description="minutes after it starts before its drift has settled (daily QA warns; "
        "commissioning waits at least this long)",
    )

    @field_validator("host")
    @classmethod
    def _host_alone(cls, v):
        """A host name or address and nothing else: it is put into the camera's URLs, where a '/',
        '@', ':', '?' or '#' would make another host the one asked, with the camera's credentials."""
        if v is not None and not _HOST_RE.fullmatch(v):
            raise ValueError(
                "is not a host name or address alone (letters, digits, '.', '-', '_'; an IPv6 address in "
                "[brackets]; the port is port:)"
            )
        return v

    @field_validator("ca_cert")
    @classmethod
    def _cert_exists(cls, v):
        if v is not None and not v.is_file():
            raise ValueError("no such certificate file")
        return v

    @model_validator(mode="after")
    def _cert_needs_https(self):
        if self.ca_cert is not None and self.scheme != "https":
            raise ValueError("ca_cert needs scheme: https")
        return self

    @field_validator("resolution", mode="before")
    @classmethod
    def _parse_resolution(cls, v):
        if isinstance(v, str):
            m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", v)
            if not m:
                raise ValueError("expected WIDTHxHEIGHT such as 640x480")
            return int(m.group(1)), int(m.group(2))
        return v

    @property
    def base_url(self) -> str:
        """``scheme://host[:port]``; a camera without a host (e.g. a replay) shows its kind and
        options instead."""
        if not self.host:
            return f"{self.kind}:" + ",".join(f"{k}={v}" for k, v in sorted(self.options.items()))
        default = 80 if self.scheme == "http" else 443
        given = self.port if "port" in self.model_fields_set else default  # https without a port: 443
        port = "" if given == default else f":{given}"
        return f"{self.scheme}://{self.host}{port}"

    @property
    def resolution_str(self) -> str:
        return f"{self.resolution[0]}x{self.resolution[1]}"

    def password(self) -> str | None:
        """The password from the environment, or None when no variable is named.

        Raises ConfigError when the variable is named but not set."""
        if self.password_env is None:
            return None
        value = os.environ.get(self.password_env)
        if value is None:
            raise ConfigError(
                f"camera {self.name!r}: environment variable {self.password_env} (its password_env) is not set"
            )
        return value


class TriggerConfig(BaseModel):
    """rig.yaml's ``trigger:`` section: the keys every backend shares, validated here, and the
    backend's own keys (``options``), kept as given and validated by the backend's own settings
    model when it is opened (``vts_hw.drivers.registry.open_trigger``): the core knows no
    backend, so a new one needs no edit here (docs/decisions/0032-neutral-trigger-log.md)."""

    model_config = ConfigDict(extra="allow", frozen=True)

    backend: str = Field(
        default="none", pattern=_NAME_RE, description="none, or a name in vts_hw.drivers.registry.TRIGGER_BACKENDS"
    )
    address: str | None = Field(default=None, description="serial port, VISA resource or DAQmx device")
    frequency_hz: float = Field(default=1.0, ge=0.1, le=1000.0)
    duty: float = Field(default=0.5, ge=0.01, le=0.99)
    high_v: float = Field(default=5.0, ge=-10, le=10)
    low_v: float = Field(default=0.0, ge=-10, le=10)
    pulse_ms: int = Field(default=100, ge=1, le=10000)

    @property
    def options(self) -> dict:
        """The backend's own keys, as given (validated when the backend is opened)."""
        return dict(self.model_extra or {})

    @model_validator(mode="after")
    def _levels(self):
        if self.low_v >= self.high_v:
            raise ValueError("low_v must be below high_v")
        if self.backend != "none" and not self.address:
            raise ValueError(f"backend {self.backend!r} needs an address")
        return self


class ToleranceWindow(_Strict):
    """QATrack+-style window: action low <= tolerance low <= tolerance high <= action high."""

    action_low: float | None = None
    tolerance_low: float | None = None
    tolerance_high: float | None = None
    action_high: float | None = None
    unit: str = ""

    @model_validator(mode="after")
    def _ordered(self):
        vals = [
            v for v in (self.action_low, self.tolerance_low, self.tolerance_high, self.action_high) if v is not None
        ]
        if vals != sorted(vals):
            raise ValueError("expected action_low <= tolerance_low <= tolerance_high <= action_high")
        return self


#: rig.yaml's calibration entries renamed for what they hold (issue 34 §1): old name -> new name
OLD_CALIBRATION_KEYS = {"stereo": "cameras", "spect": "mapping"}


class CalibrationPaths(_Strict):
    """rig.yaml's ``calibration:``, the files of the room's current calibration (a relative path
    is the file beside rig.yaml). The old names ``stereo`` and ``spect`` are still read (both
    names of one entry at once is an error); ``dump_rig`` writes the new ones."""

    cameras: Path | None = Field(
        default=None, description="the camera calibration file (any number of cameras; old name: stereo)"
    )
    mapping: Path | None = Field(default=None, description="the VTS -> SPECT mapping file (old name: spect)")

    @model_validator(mode="before")
    @classmethod
    def _old_names(cls, data):
        """``stereo``/``spect`` are the old names of ``cameras``/``mapping``: read as those."""
        if not isinstance(data, dict):
            return data
        for old, new in OLD_CALIBRATION_KEYS.items():
            if old in data:
                if data.get(new) is not None and data[old] is not None:
                    raise ValueError(f"has both {new} and {old} (the old name of {new}); keep only {new}")
                value = data[old] if data.get(new) is None else data[new]
                data = {k: v for k, v in data.items() if k not in (old, new)} | {new: value}
        return data


class StoreConfig(_Strict):
    """Where results go: ``store:`` in rig.yaml (``results:`` is its old name, still read)."""

    url: str | None = Field(
        default=None,
        min_length=1,
        description="database URL: sqlite:////path/results.sqlite or postgresql://user@host[:port]/db; "
        "default a per-user SQLite file",
    )
    password_env: str | None = Field(
        default=None,
        pattern=r"^[A-Za-z_][A-Za-z0-9_]*$",
        description="name of the environment variable holding the database password (never in the URL)",
    )

    @field_validator("url")
    @classmethod
    def _no_password_in_url(cls, v):
        if v is not None and "://" in v:
            from sqlalchemy.engine import make_url
            from sqlalchemy.exc import ArgumentError

            try:
                url = make_url(v)
            except ArgumentError:
                raise ValueError(
                    "is not a database URL (expected e.g. sqlite:////path/results.sqlite or postgresql://user@host/db)"
                ) from None
            if url.password is not None:
                raise ValueError(
                    "holds a password; remove it from the URL and name the environment "
                    "variable that holds it in store.password_env"
                ) from None
        return v


#: the old name of StoreConfig (rig.yaml's ``results:`` section)
ResultsConfig = StoreConfig


class MotionConfig(_Strict):
    """Patient motion: when the live view alerts, and what counts as one motion state."""

    alert_mm: float = Field(
        default=3.0, gt=0, le=100, description="alert when the body has moved more than this (mm, breathing excluded)"
    )
    alert_deg: float = Field(default=2.0, gt=0, le=90, description="... or turned more than this (deg)")
    alert_after_s: float = Field(
        default=1.0, ge=0, le=60, description="for longer than this (s): a cough or a twitch does not alert"
    )
    alert_command: list[str] | None = Field(
        default=None,
        min_length=1,
        description="a command run on each alert (argv list, no shell), e.g. [notify-send, VTS]; the alert's "
        "text is its last argument",
    )
    blind_alert_s: float = Field(
        default=3.0,
        gt=0,
        le=600,
        description="an alert of its own when the patient has not been tracked for longer "
        "than this (s): a camera lost, too few markers, frames too late",
    )
    blind_max_share: float = Field(
        default=0.2,
        ge=0,
        le=1,
        description="a scan whose patient was not tracked for more than this share of the "
        "live time, or that learned no reference, was not watched: exit 4",
    )
    state_mm: float = Field(
        default=2.0, gt=0, le=100, description="a motion state: an interval of body pose within this (mm) ..."
    )
    state_deg: float = Field(default=1.0, gt=0, le=90, description="... and this (deg)")


def _set(section) -> bool:
    """A config section that says something (not missing, empty, or all null)."""
    if isinstance(section, dict):
        return any(v is not None for v in section.values())
    return section is not None


class RigConfig(_Strict):
    rig: str = Field(default="vts", pattern=_NAME_RE)
    cameras: list[CameraConfig] = Field(min_length=1)
    trigger: TriggerConfig = TriggerConfig()
    tolerances: dict[str, ToleranceWindow] = Field(default_factory=dict)
    calibration: CalibrationPaths = CalibrationPaths()
    store: StoreConfig = StoreConfig()
    motion: MotionConfig = MotionConfig()
    aim: AimSettings = AimSettings()  # goals of `vts camera aim` (vision/aim_settings.py)
    qatrack: QATrackConfig | None = None  # pushing results to QATrack+ (config_qatrack.py)
    camera_setup: CameraSetupConfig = CameraSetupConfig()  # what `vts camera setup` sets (config_setup.py)
    warmup: WarmupSettings = WarmupSettings()  # how commissioning watches the pictures settle (config_warmup.py)
    recordings_dir: Path | None = None
    _source: Path | None = PrivateAttr(default=None)  # the file it was read from

    @model_validator(mode="before")
    @classmethod
    def _old_results_key(cls, data):
        """``results:`` is the old name of ``store:``: read it as that; both at once is an error."""
        if isinstance(data, dict) and "results" in data:
            if _set(data.get("store")) and _set(data["results"]):
                raise ValueError("store and results (the old name of store) are both given; keep only store")
            if _set(data.get("store")):  # an empty results: section beside store: is nothing
                return {k: v for k, v in data.items() if k != "results"}
            data = {("store" if k == "results" else k): v for k, v in data.items() if k != "store"}
        return data

    @property
    def results(self) -> StoreConfig:
        """The store section by its old name (``rig.results.url``)."""
        return self.store

    @property
    def digest(self) -> str:
        """sha256 of the file this config was read from ("" when it was not read from one)."""
        return config_digest(self._source) if self._source is not None and self._source.exists() else ""

    @field_validator("tolerances")
    @classmethod
    def _known_metrics(cls, v: dict):
        known = default_windows()  # the tolerance table's and the catalog entries' own
        unknown = sorted(set(v) - set(known))
        if unknown:
            raise ValueError(
                f"names {unknown[0]!r}, which is not a metric with a tolerance window (known: {', '.join(known)})"
            )
        return v

    @model_validator(mode="after")
    def _unique_names(self):
        names = [c.name for c in self.cameras]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"camera names must be unique; repeated: {', '.join(dup)}")
        return self

    def camera(self, name: str) -> CameraConfig:
        for c in self.cameras:
            if c.name == name:
                return c
        known = ", ".join(c.name for c in self.cameras)
        raise ConfigError(f"no camera named {name!r} in the rig config (known: {known})")


def _loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def _describe(err: ErrorDetails) -> str:
    typ = err.get("type", "")
    if typ == "missing":
        return "is required but missing"
    if typ == "extra_forbidden":
        return "is not a known key"
    msg = err.get("msg", "is invalid")
    msg = re.sub(r"^Value error, ", "", msg)
    got = err.get("input")
    if typ not in ("model_type",) and not isinstance(got, (dict, list)) and "password" not in msg:
        # (a value refused for holding a password is never echoed)
        shown = repr(got)
        shown = shown if len(shown) <= 80 else shown[:77] + "..."
        return f"{msg[0].lower() + msg[1:]} (got {shown})"
    return msg[0].lower() + msg[1:]


def parse_rig(data, source: str = "rig.yaml") -> RigConfig:
    """Validate an already-parsed mapping; errors name ``source``."""
    if not isinstance(data, dict):
        got = {type(None): "an empty document", list: "a list", str: "a single string"}.get(
            type(data), f"a single {type(data).__name__}"
        )
        raise ConfigError(f"{source}: expected a mapping (rig:, cameras:, ...) at the top level, got {got}")
    try:
        return RigConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(validation_message(source, exc)) from None


def validation_message(source: str, exc: ValidationError, prefix: tuple = ()) -> str:
    """One sentence for a pydantic error: the file, the dotted key (under ``prefix``, e.g.
    ``("trigger",)`` for a section validated on its own) and what was expected."""
    first = exc.errors()[0]
    more = len(exc.errors()) - 1
    tail = f" ({more} more error{'s' if more > 1 else ''})" if more else ""
    return f"{source}: {_loc(tuple(prefix) + tuple(first['loc']))} {_describe(first)}{tail}"


MAX_CONFIG_BYTES = 1 << 20  # a rig.yaml is a few kB; anything this large is not one
MAX_YAML_DEPTH = 32  # rig.yaml nests 4 levels deep
MAX_YAML_NODES = 100_000  # a rig.yaml has some hundred; aliases that expand beyond: a YAML bomb


def _read_text(p: Path) -> str:
    """The config file's text; ConfigError naming the file when it is not UTF-8 YAML text."""
    try:
        with open_checked(p, ANY_SIZE, "rig config") as f:  # a FIFO would block for ever; a device never ends
            raw = f.read(MAX_CONFIG_BYTES + 1)
    except TooLarge as exc:
        raise ConfigError(str(exc)) from None
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such config file (give --config or set {ENV_CONFIG})") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the config file ({exc.strerror or exc})") from None
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{p}: larger than {MAX_CONFIG_BYTES >> 20} MB, so not a rig config file")
    nul = raw.find(b"\x00")
    if nul >= 0:
        raise ConfigError(
            f"{p}: not a YAML text file (a NUL byte at byte {nul}: a binary file, or text saved as UTF-16)"
        )
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{p}: not UTF-8 text (byte {exc.start} cannot be decoded); save the config as UTF-8"
        ) from None


def _check_depth(text: str, p: Path) -> None:
    """Refuse deep nesting before the (recursive) composer sees it."""
    depth = 0
    for ev in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(ev, yaml.CollectionStartEvent):
            depth += 1
            if depth > MAX_YAML_DEPTH:
                at = f" at line {ev.start_mark.line + 1}" if ev.start_mark is not None else ""
                raise ConfigError(f"{p}: nested more than {MAX_YAML_DEPTH} levels deep{at}, so not a rig config")
        elif isinstance(ev, yaml.CollectionEndEvent):
            depth -= 1


def _expanded_size(node, memo: dict) -> int:
    """Nodes of the document with every alias (and merge key) expanded; linear time."""
    key = id(node)
    if key in memo:
        return memo[key]
    memo[key] = 1  # a recursive alias counts once
    n = 1
    if isinstance(node, yaml.SequenceNode):
        n += sum(_expanded_size(c, memo) for c in node.value)
    elif isinstance(node, yaml.MappingNode):
        n += sum(_expanded_size(k, memo) + _expanded_size(v, memo) for k, v in node.value)
    memo[key] = n
    return n


def _load_yaml(text: str, p: Path):
    """``yaml.safe_load``, refusing YAML bombs (aliases that expand to millions of nodes) and
    deep nesting before anything is built from them."""
    _check_depth(text, p)
    loader = yaml.SafeLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        if _expanded_size(node, {}) > MAX_YAML_NODES:
            raise ConfigError(
                f"{p}: its aliases (*name) expand to more than {MAX_YAML_NODES:,} "
                f"values, which no rig config needs (a YAML bomb?)"
            )
        return loader.construct_document(node)
    finally:
        loader.dispose()


def load_rig(path: str | os.PathLike | None = None) -> RigConfig:
    """Load and validate a rig.yaml; ``None`` means $VTS_CONFIG, then ./rig.yaml."""
    if path is None:
        path = os.environ.get(ENV_CONFIG) or "rig.yaml"
    p = Path(path)
    text = _read_text(p)
    try:
        data = _load_yaml(text, p)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark else ""
        problem = getattr(exc, "problem", None)
        raise ConfigError(f"{p}: not valid YAML{where}" + (f" ({problem})" if problem else "")) from None
    except (ValueError, OverflowError) as exc:  # a value YAML cannot build, e.g. 2024-02-30
        raise ConfigError(f"{p}: not valid YAML (a value cannot be read: {exc})") from None
    rig = parse_rig(data, str(p))
    # a relative calibration path is the file beside rig.yaml, for every command that reads it
    # (they once took it from the working folder or from rig.yaml's, each its own way)
    cal = rig.calibration
    rig = rig.model_copy(
        update={
            "calibration": CalibrationPaths(
                cameras=_beside(p.parent, cal.cameras), mapping=_beside(p.parent, cal.mapping)
            )
        }
    )
    rig._source = p
    return rig


def _beside(base: Path, path: Path | None) -> Path | None:
    return path if path is None or path.is_absolute() else base / path


def config_digest(path: str | os.PathLike) -> str:
    """sha256 of the config file's bytes (stored with runs and recordings)."""
    return hashlib.sha256(read_bytes(path, MAX_CONFIG_BYTES, "rig config")).hexdigest()


def dump_rig(cfg: RigConfig) -> str:
    """YAML text of a config (used by the simulated rig to write DIR/rig.yaml)."""
    data = cfg.model_dump(mode="json", exclude_none=True, exclude_defaults=True)
    return yaml.safe_dump(data, sort_keys=False)
