"""Opening a VISA instrument, and what a VISA failure means, in one sentence naming the resource.

:func:`open_message_resource` opens ``address`` through a VISA library (``""``: pyvisa's default,
the IVI/NI VISA where installed, else pyvisa-py; ``"@py"``; ``"path/model.yaml@sim"`` for
pyvisa-sim) with ``\\n`` as read and write termination, which a ``TCPIP::HOST::PORT::SOCKET``
resource needs (a raw socket has no end-of-message signal: a 33500 ends every response with
``\\n`` and takes commands ending in it), and the timeout for both connecting and answering.

:func:`visa_failure` turns what pyvisa or its backend raises (a refused or lost connection, a
timeout, an unknown host, a VISA status) into a :class:`~.trigger.TriggerError` that says what
happened to which resource. pyvisa-py connects a SOCKET resource lazily in effect: a refused
connection shows on the first write, so the first command names it.
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import importlib.resources
import socket
from pathlib import Path
from typing import Any

from vts_hw.drivers.trigger import TriggerError

SIM_PACKAGE = "vts_hw.sim_devices"
SIM_YAML = "keysight_33500.yaml"

_files = contextlib.ExitStack()
atexit.register(_files.close)


def sim_yaml_path() -> Path:
    """The shipped pyvisa-sim model, as a file path (package data of ``vts_hw.sim_devices``)."""
    ref = importlib.resources.files(SIM_PACKAGE).joinpath(SIM_YAML)
    if isinstance(ref, Path):
        return ref
    return _files.enter_context(importlib.resources.as_file(ref))  # pragma: no cover - zipped install


def is_visa_error(e: BaseException) -> bool:
    """An error of the connection or the VISA layer (not a bug in our code)."""
    try:
        import pyvisa.errors
    except ImportError:  # pragma: no cover - pyvisa is a dependency
        return isinstance(e, (TimeoutError, OSError))
    return isinstance(e, (pyvisa.errors.Error, TimeoutError, OSError)) or _connect_failure(e)


def _connect_failure(e: BaseException) -> bool:
    # pyvisa-py raises a bare Exception("could not connect: ...") for an unknown host or a
    # connection that timed out
    return type(e) is Exception and str(e).startswith("could not connect")


def visa_failure(
    e: BaseException, name: str, address: str, command: str | None, timeout_ms: float | None
) -> TriggerError:
    """``e`` as one sentence: ``name`` at ``address``, what happened, during which command."""
    during = f" {command!r}" if command else ""
    where = f"{name}: the instrument at {address}"
    code = getattr(e, "error_code", None)
    tmo: object
    lost: object
    refused_codes: tuple[object, ...]
    try:
        from pyvisa import constants

        tmo, lost = constants.StatusCode.error_timeout, constants.StatusCode.error_connection_lost
        refused_codes = (constants.StatusCode.error_resource_not_found,)
    except ImportError:  # pragma: no cover
        tmo = lost = object()
        refused_codes = ()
    if (
        isinstance(e, ConnectionRefusedError)
        or getattr(e, "errno", None) == errno.ECONNREFUSED
        or code in refused_codes
    ):
        text = (
            f"{where} refused the connection (nothing listens there: is it switched on, "
            f"and are the address and port right?)"
        )
    elif code == tmo or isinstance(e, (TimeoutError, socket.timeout)):
        secs = f" within {timeout_ms / 1000:g} s" if timeout_ms else ""
        text = f"{where} did not answer{during}{secs}"
    elif code == lost or isinstance(e, (ConnectionResetError, BrokenPipeError, ConnectionAbortedError)):
        text = f"{where} closed the connection (it was switched off or unplugged, or another program took it)"
    elif _connect_failure(e):
        detail = str(e).partition(":")[2].strip()
        if "Name or service not known" in detail or "nodename nor servname" in detail:
            detail = "no such host name"
        elif "error_timeout" in detail:
            detail = "no answer to the connection within the timeout"
        text = f"{name}: cannot connect to {address} ({detail})"
    elif isinstance(e, UnicodeDecodeError):  # pyvisa decodes a reply as ASCII
        text = f"{where} answered{during} with bytes that are not text: {e.object[:40]!r}"
    else:
        text = f"{where} failed{' on ' + repr(command) if command else ''} ({e})"
    return TriggerError(text)


def open_message_resource(address: str, library: str, timeout_ms: int, name: str):
    """Open ``address`` through ``library``; a TriggerError naming it when that is impossible."""
    import pyvisa

    try:
        rm = pyvisa.ResourceManager(library)
    except Exception as e:
        raise TriggerError(
            f"{name}: cannot load the VISA library {library or '(default)'!r} to reach {address}: {e}"
        ) from e
    if type(rm.visalib).__module__.startswith("pyvisa_sim"):
        _fresh_sim_devices(rm, name)
        # pyvisa-sim "opens" any address and then never answers: say what is wrong instead
        sim: Any = rm.visalib  # pyvisa-sim's library (no types): its simulated devices
        known = sim.devices.list_resources()
        try:
            canonical = pyvisa.rname.to_canonical_name(address)
        except Exception:
            canonical = address
        if canonical not in known:
            raise TriggerError(
                f"{name}: cannot open {address}: the simulated model at "
                f"{rm.visalib.library_path} has only {', '.join(known)}"
            )
    else:
        _check_address(address, name)
    try:
        return rm.open_resource(
            address, read_termination="\n", write_termination="\n", timeout=timeout_ms, open_timeout=timeout_ms
        )
    except pyvisa.errors.VisaIOError as e:
        if e.error_code == pyvisa.constants.StatusCode.error_invalid_resource_name:
            raise _not_an_address(address, name) from None
        raise visa_failure(e, name, address, None, timeout_ms) from None
    except Exception as e:
        if is_visa_error(e):
            raise visa_failure(e, name, address, None, timeout_ms) from None
        raise TriggerError(f"{name}: cannot open {address} through {library or 'the default VISA'}: {e}") from e


def _not_an_address(address: str, name: str) -> TriggerError:
    return TriggerError(
        f"{name}: {address!r} is not a VISA address (e.g. "
        f"TCPIP::192.168.1.20::5025::SOCKET or TCPIP::192.168.1.20::INSTR)"
    )


def _check_address(address: str, name: str) -> None:
    """A VISA address, and for the LAN a host name that resolves: said plainly before a VISA
    backend fails on it in its own words (pyvisa-py answers an unknown VXI-11 host with EBADF)."""
    from pyvisa import rname

    try:
        parsed = rname.parse_resource_name(address)
    except rname.InvalidResourceName:
        raise _not_an_address(address, name) from None
    host = getattr(parsed, "host_address", None)
    if host:
        try:
            socket.getaddrinfo(host, None)
        except (socket.gaierror, UnicodeError):
            raise TriggerError(
                f"{name}: cannot reach {address}: no host is called {host!r} (check the trigger address in rig.yaml)"
            ) from None


def _fresh_sim_devices(rm, name: str) -> None:
    """Give the next session a freshly parsed simulated device.

    pyvisa keeps one library object per YAML path for the whole process (and one
    ResourceManager per library), and pyvisa-sim keeps device state in that object, so a new
    ResourceManager alone would hand a new instance the old state (pyvisa-sim issues #82, #83).
    Re-parsing the definitions gives sessions opened from now on new devices; sessions already
    open keep theirs.
    """
    lib = rm.visalib
    try:
        from pyvisa_sim import parser

        path = str(lib.library_path)
        lib.devices = parser.get_devices("default.yaml", True) if path == "unset" else parser.get_devices(path, False)
    except Exception as e:
        raise TriggerError(f"{name}: cannot load a fresh simulated device from {lib.library_path}: {e}") from e


def query_within(resource, command: str) -> str:
    """``resource.query(command)`` with one deadline (``resource.timeout`` ms) for the whole reply.

    pyvisa-py looks at its timeout only when a read brings nothing, so an instrument that
    trickles its reply a byte at a time is read for as long as it trickles (a 40-byte ``*IDN?``
    at a byte a second: 40 s, and each query after it as long). Through pyvisa-py the reply is
    read here a byte at a time against the deadline; a timeout is pyvisa's own VisaIOError."""
    import time
    import warnings

    import pyvisa

    timeout_ms = getattr(resource, "timeout", None)
    lib = getattr(resource, "visalib", None)
    if timeout_ms is None or lib is None or not type(lib).__module__.startswith("pyvisa_py"):
        return resource.query(command)
    resource.write(command)
    deadline = time.monotonic() + timeout_ms / 1000.0
    term = (resource.read_termination or "\n").encode("ascii")
    reply = bytearray()
    with warnings.catch_warnings():  # a read of the 1 byte asked for is "max count read": no news
        warnings.simplefilter("ignore", pyvisa.errors.VisaIOWarning)
        while not reply.endswith(term):
            if time.monotonic() > deadline:
                raise pyvisa.errors.VisaIOError(pyvisa.constants.StatusCode.error_timeout)
            chunk, _ = lib.read(resource.session, 1)
            reply += chunk
    return bytes(reply[: -len(term)]).decode(resource.encoding)
