"""Axis cameras as they announce themselves: DNS-SD over mDNS and SSDP, then confirmed over VAPIX.

``search(timeout, interfaces)`` runs both searches at once (:mod:`.mdns`, :mod:`.ssdp`) and
merges what they heard by serial number (an Axis serial number is the camera's MAC address);
``confirm(found, user, password)`` asks each camera found for its device info
(``basicdeviceinfo.cgi``, or the ``Brand``/``Properties`` parameters of older firmware) and
says whether the camera agrees with its announcement. Nothing here writes a file: the rig.yaml
skeleton is :mod:`vts_hw.rig_file`'s.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Literal

from vts_hw.camera import CameraError
from vts_hw.config import CameraConfig
from vts_hw.drivers.axis import CameraUnauthorized
from vts_hw.drivers.discovery import mdns as mdns_mod
from vts_hw.drivers.discovery import ssdp as ssdp_mod
from vts_hw.drivers.discovery.announcement import Announcement, DiscoveryFailed
from vts_hw.drivers.registry import open_camera


@dataclass
class Found:
    """One camera found: where, what it said it is, and what VAPIX confirmed (``firmware`` and
    ``confirmed`` stay empty until :func:`confirm`; ``problem`` says why it could not be)."""

    host: str
    port: int
    serial: str
    model: str = ""
    scheme: Literal["http", "https"] = "http"
    sources: tuple[str, ...] = ()
    firmware: str = ""
    confirmed: bool = False
    problem: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"


def merge(announcements) -> list[Found]:
    """One :class:`Found` per camera: announcements with the same serial number (else the same
    address) are one camera; its address is the first announcement's, and an announcement of
    the same serial at another address is noted."""
    out: dict[str, Found] = {}
    for a in announcements:
        key = a.serial.upper() or f"{a.host}:{a.port}"
        f = out.get(key)
        if f is None:
            out[key] = Found(a.host, a.port, a.serial.upper(), a.model, a.scheme, (a.source,))
            continue
        if a.source not in f.sources:
            f.sources += (a.source,)
        if not f.model and a.model:
            f.model = a.model
        if (a.host, a.port) != (f.host, f.port):
            note = f"{a.source} also announced it at {a.host}:{a.port}"
            if note not in f.notes:
                f.notes.append(note)
    return sorted(out.values(), key=lambda f: (f.host, f.port, f.serial))


def search(timeout: float, interfaces: list[str] | None = None, *, mdns: bool = True, ssdp: bool = True) -> list[Found]:
    """Listen for ``timeout`` seconds on ``interfaces`` (IPv4 addresses of this host; None: all)
    with both protocols at once. A protocol that cannot run here (no such interface, port
    taken) is an :class:`~vts_hw.errors.DeviceError` naming it."""
    jobs: list[tuple[str, Callable[[], list[Announcement]]]] = []
    if mdns:
        jobs.append(("mdns", lambda: mdns_mod.browse(timeout, interfaces)))
    if ssdp:
        jobs.append(("ssdp", lambda: ssdp_mod.search(timeout, interfaces)))
    results: dict[str, list[Announcement]] = {}
    errors: dict[str, BaseException] = {}

    def run(name, job):
        try:
            results[name] = job()
        except BaseException as exc:  # re-raised below, in the caller's thread
            errors[name] = exc

    threads = [threading.Thread(target=run, args=job, name=f"discover-{job[0]}", daemon=True) for job in jobs]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for name in ("mdns", "ssdp"):
        if name in errors:
            raise errors[name]
    return merge([a for name in ("mdns", "ssdp") for a in results.get(name, [])])


def confirm(found: Found, user: str | None, password_env: str | None, timeout: float = 5.0) -> Found:
    """``found`` with its model, serial number and firmware as the camera itself tells them
    over VAPIX (the password from the environment variable ``password_env``, when it is set);
    ``confirmed`` is False (and ``problem`` says why) when it cannot be asked or does not agree
    with its announcement."""
    has_password = bool(password_env and os.environ.get(password_env) is not None)
    cfg = CameraConfig(
        name=found.serial or "camera",
        host=found.host,
        port=found.port,
        scheme=found.scheme,
        user=user or "root",
        password_env=password_env if has_password else None,
        timeout_s=timeout,
    )
    try:
        with open_camera(cfg) as cam:
            info = cam.device_info()
    except CameraUnauthorized as exc:
        why = (
            f"it asks for a password: set {password_env} (the cameras' password)"
            if not has_password and password_env
            else str(exc)
        )
        return replace(found, confirmed=False, problem=why)
    except CameraError as exc:
        return replace(found, confirmed=False, problem=str(exc))
    serial = info.get("SerialNumber", "").upper()
    model = info.get("ProdShortName") or info.get("ProdNbr") or found.model
    firmware = info.get("Version", "")
    if found.serial and serial and serial != found.serial:
        return replace(
            found,
            firmware=firmware,
            confirmed=False,
            problem=f"the camera at {found.address} says its serial number is {serial}, "
            f"not {found.serial} as announced",
        )
    return replace(found, serial=serial or found.serial, model=model, firmware=firmware, confirmed=True, problem="")


__all__ = ["Announcement", "DiscoveryFailed", "Found", "merge", "search", "confirm"]
