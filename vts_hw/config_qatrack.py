"""rig.yaml's ``qatrack:`` section: where results are pushed in the clinic's QATrack+.

    qatrack:
      url: https://qatrack.example.org/        # the site's root; the API is under api/
      unit: SPECT room 1                        # the QATrack+ unit of this rig
      time_zone: America/Toronto                # the site's TIME_ZONE (QATrack+ reads times in it)
      token_env: QATRACK_TOKEN                  # or user_env + password_env (then /api/get-token/)
      lists:
        daily:                                  # a procedure name as stored (daily, drift, sphere-steps ...)
          test_list: VTS daily                  # the test list assigned to the unit
          macros: {cam1/drift_x_px: cam1_dx, cam1/drift_y_px: cam1_dy}
          ignore: ["*/M*/*", "*/drift_sd_px"]   # measurements deliberately not sent

A measurement is named ``SUBJECT/METRIC`` (the metric is the part after the last ``/``, e.g.
``cam1/drift_x_px``, ``x/steps_slope``). Every measurement of a pushed run must be mapped to a
macro or matched by an ``ignore`` pattern, so that no list is sent half-filled by accident.
Credentials never live in the file: it names the environment variables that hold them.
See docs/decisions/0042-qatrack-push.md.
"""

from __future__ import annotations

import os
import re
from typing import Literal
from urllib.parse import urlsplit

from pydantic import Field, field_validator, model_validator

from vts_hw import catalog
from vts_hw.config_base import Strict
from vts_hw.errors import ConfigError
from vts_hw.site_time import site_zone

_ENV_RE = r"^[A-Za-z_][A-Za-z0-9_]*$"
_MACRO_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")  # QATrack+ macro names are identifiers
_METRIC_RE = re.compile(r"^[A-Za-z0-9_.:-]+$")
#: what a ``lists:`` key may be: the procedure names runs are stored under (as the catalog holds
#: them at import; the check reads the catalog itself)
PROCEDURE_RE = catalog.stored_name_pattern()


class QATrackList(Strict):
    """One procedure's test list in QATrack+ and its metric -> macro mapping."""

    test_list: str = Field(min_length=1, description="the name of the test list assigned to the unit")
    macros: dict[str, str] = Field(min_length=1, description="SUBJECT/METRIC (or METRIC) -> QATrack+ macro name")
    ignore: list[str] = Field(
        default_factory=list, description="glob patterns of SUBJECT/METRIC not sent (e.g. '*/M*/*')"
    )

    @field_validator("macros")
    @classmethod
    def _names(cls, v: dict):
        for key, macro in v.items():
            metric = key.rsplit("/", 1)[-1]
            if not metric or not _METRIC_RE.match(metric) or key.startswith("/"):
                raise ValueError(f"{key!r} is not SUBJECT/METRIC (e.g. cam1/drift_x_px)")
            if not _MACRO_RE.match(macro):
                raise ValueError(f"{macro!r} (for {key}) is not a QATrack+ macro name (letters, digits, _)")
        seen: dict[str, str] = {}
        for key, macro in v.items():
            if macro in seen:
                raise ValueError(f"macro {macro!r} is given to both {seen[macro]} and {key}")
            seen[macro] = key
        return v


class QATrackConfig(Strict):
    """The clinic's QATrack+: its root URL, this rig's unit, credentials from the environment."""

    url: str = Field(description="root of the QATrack+ site, http(s)://host[:port]/[path/]")
    unit: str = Field(min_length=1, description="the unit's name in QATrack+")
    time_zone: str = Field(
        description="the site's TIME_ZONE setting (an IANA name such as America/Toronto): "
        "QATrack+ reads the work times it is sent as wall-clock times of that zone"
    )
    token_env: str | None = Field(
        default=None, pattern=_ENV_RE, description="environment variable holding an API token"
    )
    user_env: str | None = Field(
        default=None, pattern=_ENV_RE, description="... or the variables holding a user name and ..."
    )
    password_env: str | None = Field(
        default=None, pattern=_ENV_RE, description="... password, exchanged at /api/get-token/"
    )
    timeout_s: float = Field(default=10.0, gt=0, le=300, description="per request")
    report: Literal["html", "pdf", "none"] = Field(
        default="html", description="attach the drift report as of the run (html or pdf), or none"
    )
    plots: bool = Field(default=True, description="attach the run's drift plot(s) as PNG")
    lists: dict[str, QATrackList] = Field(min_length=1, description="procedure -> test list and macros")

    @field_validator("url")
    @classmethod
    def _url(cls, v: str):
        parts = urlsplit(v.strip())
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise ValueError("expected the site's root as http(s)://host[:port]/")
        if parts.username or parts.password:
            raise ValueError("the URL must not hold a user or password (name environment variables instead)")
        if parts.query or parts.fragment:
            raise ValueError("the URL is the site's root, without ?query or #fragment")
        return v.strip() if v.strip().endswith("/") else v.strip() + "/"

    @field_validator("time_zone")
    @classmethod
    def _zone(cls, v: str):
        site_zone(v)  # ValueError naming the zone when it is not one
        return v

    @field_validator("lists")
    @classmethod
    def _procedures(cls, v: dict):
        for name in v:
            if not re.match(catalog.stored_name_pattern(), name):
                raise ValueError(f"{name!r} is not a procedure stored as runs ({catalog.stored_names_text()})")
        return v

    @model_validator(mode="after")
    def _credentials(self):
        login = (self.user_env is not None, self.password_env is not None)
        if self.token_env is not None and any(login):
            raise ValueError("give token_env, or user_env and password_env, not both")
        if self.token_env is None and login != (True, True):
            raise ValueError("needs token_env, or user_env and password_env (environment variable names)")
        return self

    @property
    def api(self) -> str:
        return self.url + "api/"

    def credentials(self) -> tuple[str, ...]:
        """``("token", TOKEN)`` or ``("login", USER, PASSWORD)`` from the environment;
        ConfigError naming the variable (never its value) when one is not set."""
        names = [self.token_env] if self.token_env else [self.user_env or "", self.password_env or ""]
        values = []
        for name in names:
            value = os.environ.get(name)
            if not value:
                raise ConfigError(
                    f"qatrack: environment variable {name} is not set "
                    f"(it holds the QATrack+ {'token' if self.token_env else 'login'})"
                )
            values.append(value)
        return ("token", *values) if self.token_env else ("login", *values)
