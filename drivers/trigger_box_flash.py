"""Flashing the trigger box: build its firmware, upload it through the bootloader, ask the box.

:func:`flash` is ``vts trigger flash``: the Intel HEX comes from ``make -C firmware`` (a checkout)
or ``--hex FILE`` (an installed vts-hw has no firmware sources); the version it holds is read from
the image itself (the ``*IDN?`` reply's version string, which the firmware keeps in flash); the
port is checked (there, not held by another program); avrdude writes and verifies it
(:mod:`vts_hw.drivers.avrdude`, its output in ``<hex>.avrdude.log`` beside the hex); then the box
is asked ``*IDN?`` through the trigger box driver until it answers, and must name that version.
See docs/decisions/0070-trigger-flash.md.
"""

from __future__ import annotations

import errno
import fcntl
import io
import os
import re
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from vts_hw.bounded import TooLarge, read_text
from vts_hw.drivers import avrdude
from vts_hw.drivers.trigger import TriggerError
from vts_hw.drivers.trigger_box import TriggerBox
from vts_hw.drivers.trigger_box_protocol import BoxGone
from vts_hw.errors import DeviceError, UsageError
from vts_hw.files import open_fd
from vts_hw.lifeline import child_options

HEX_NAME = "trigger_box.hex"
#: an Intel HEX of the ATmega328P's 32 KiB is ~90 kB (16-byte records), ~430 kB at one byte a record
HEX_MAX = 4 * 2**20
#: the firmware's identity in its flash: the start of its *IDN? reply, and the version string
_IDN_MARK = b"VTS,TRIGGERBOX,"
_VERSION = re.compile(rb",(\d+\.\d+(?:\.\d+)?(?:[-+][0-9A-Za-z.]+)?)\x00")
_CONFIG_VERSION = re.compile(r'#define\s+FW_VERSION\s+"([^"]+)"')


class FlashError(DeviceError):
    """The box failed during flashing or did not confirm it (exit 4)."""


@dataclass(frozen=True)
class Firmware:
    """The image to flash: its file, its size and the version it will answer ``*IDN?`` with."""

    hex: Path
    version: str
    size: int
    built: bool  # built here from the sources (else given with --hex)


@dataclass(frozen=True)
class Flashed:
    """The result: what was written and verified, and what the box said afterwards."""

    firmware: Firmware
    upload: avrdude.Upload
    identity: str  # the box's *IDN? reply
    serial: str
    confirm_s: float  # how long the box took to answer after the upload


def firmware_dir() -> Path:
    """``firmware/`` of a checkout (``$VTS_FIRMWARE_DIR`` overrides it); absent when installed."""
    env = os.environ.get("VTS_FIRMWARE_DIR")
    return Path(env) if env else Path(__file__).resolve().parents[1] / "firmware"


def build(fw: Path | None = None) -> Path:
    """``make -C firmware build/trigger_box.hex``; the hex. UsageError (exit 2) when there are no
    sources (then --hex is needed) or the build fails (make's last lines in the sentence)."""
    fw = fw or firmware_dir()
    if not (fw / "Makefile").is_file():
        raise UsageError(
            f"no trigger box firmware sources here ({fw} has no Makefile: an installed vts-hw has "
            f"none): give the firmware to flash with --hex FILE"
        )
    proc = subprocess.run(
        ["make", "-C", str(fw), "--quiet", f"build/{HEX_NAME}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        stdin=subprocess.DEVNULL,
        **child_options(),
    )
    if proc.returncode != 0:
        tail = " | ".join(proc.stdout.strip().splitlines()[-3:])
        raise UsageError(f"building the trigger box firmware in {fw} failed (make exit {proc.returncode}): {tail}")
    return fw / "build" / HEX_NAME


def read_image(path: Path) -> tuple[bytes, int]:
    """The flash image of an Intel HEX file (from address 0, gaps 0xFF) and its byte count.
    UsageError naming the file when it cannot be read or is not Intel HEX."""
    from intelhex import IntelHex, IntelHexError

    ih = IntelHex()
    try:  # with a bound, and never a device or FIFO (--hex /dev/zero, a pipe: they never end)
        text = read_text(path, HEX_MAX, "firmware to flash (Intel HEX)", encoding="ascii")
        ih.loadhex(io.StringIO(text))
    except TooLarge as e:
        raise UsageError(str(e)) from None
    except (OSError, IntelHexError, ValueError) as e:  # UnicodeDecodeError is a ValueError
        why = (
            e.strerror
            if isinstance(e, OSError) and e.strerror
            else ("it is not ASCII text" if isinstance(e, UnicodeDecodeError) else (str(e).splitlines() or [""])[0])
        )
        raise UsageError(f"{path}: not a firmware to flash: cannot be read as Intel HEX ({why})") from None
    if not len(ih):
        raise UsageError(f"{path}: not a firmware to flash: the Intel HEX file holds no data")
    if ih.minaddr() < 0 or ih.maxaddr() >= 32 * 1024:
        raise UsageError(
            f"{path}: not a firmware to flash: it spans 0x{ih.minaddr():x}..0x{ih.maxaddr():x}, "
            f"outside the ATmega328P's 32 KiB of flash"
        )
    return ih.tobinstr(start=0), len(ih)


def image_version(image: bytes, path: Path) -> str:
    """The version the image answers ``*IDN?`` with; UsageError when it is no trigger box firmware."""
    found = {m.group(1).decode() for m in _VERSION.finditer(image)}
    if _IDN_MARK not in image or len(found) != 1:
        what = "no" if not found else f"{len(found)} candidate ({', '.join(sorted(found))})"
        raise UsageError(
            f"{path}: not a trigger box firmware: it holds {what} *IDN? version string"
            + ("" if _IDN_MARK in image else " and no 'VTS,TRIGGERBOX,' reply")
        )
    return found.pop()


def source_version(fw: Path) -> str | None:
    """``FW_VERSION`` of the sources (firmware/trigger_box/config.h), if there."""
    try:
        m = _CONFIG_VERSION.search(read_text(fw / "trigger_box" / "config.h", what="firmware source"))
    except (OSError, ValueError, TooLarge):
        return None
    return m.group(1) if m else None


def firmware(hex_path: Path | None) -> Firmware:
    """The image to flash: --hex FILE, else built from the sources."""
    built = hex_path is None
    fw = firmware_dir()
    path = build(fw) if hex_path is None else hex_path
    image, size = read_image(path)
    version = image_version(image, path)
    if built and (src := source_version(fw)) is not None and src != version:
        raise UsageError(
            f"{path}: holds version {version}, but {fw}/trigger_box/config.h says {src}: "
            f"the build is stale (make -C {fw} clean)"
        )
    return Firmware(path, version, size, built)


def check_port(port: str) -> int:
    """Open ``port`` and lock it (flock, as pyserial's exclusive mode does) so no other program
    opens it for the duration; the descriptor to close afterwards. FlashError (exit 4) naming the
    port when it is not there or another program holds it."""
    if not os.path.exists(port):
        raise FlashError(f"{port} does not exist: is the trigger box plugged in? (ls /dev/ttyACM* /dev/ttyUSB*)")
    try:
        fd = os.open(port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError as e:
        if e.errno == errno.EBUSY:
            raise FlashError(
                f"{port} is busy: another program holds it (a serial terminal, the console, "
                f"ModemManager): close it and flash again"
            ) from None
        raise FlashError(f"{port} cannot be opened: {e.strerror}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise FlashError(
            f"{port} is busy: another program has it open and locked (a vts command, a serial "
            f"terminal): close it and flash again"
        ) from None
    return fd


def confirm(port: str, expected: str, timeout: float = 15.0, open_box=TriggerBox) -> tuple[str, str, float]:
    """Ask the freshly flashed box ``*IDN?`` until it answers (it resets when the port opens: the
    bootloader waits about a second first), and check it names ``expected``. (reply, serial, s)."""
    t0 = time.monotonic()
    last = "no answer"
    while time.monotonic() - t0 < timeout:
        try:
            box = open_box(port, timeout=1.0)
        except TriggerError as e:
            last = str(e)
            time.sleep(0.2)
            continue
        try:
            while time.monotonic() - t0 < timeout:
                try:
                    ident = box.identify()
                except BoxGone as e:
                    last = str(e)
                    break
                except TriggerError as e:  # no answer yet, or the bootloader's bytes
                    last = str(e)
                    continue
                if ident.firmware != expected:
                    raise FlashError(
                        f"the box on {port} answers firmware version {ident.firmware} after flashing, "
                        f"not {expected} just written: it is not running what was flashed"
                    )
                return ident.raw, ident.serial, time.monotonic() - t0
        finally:
            box.close()
    raise FlashError(
        f"the box on {port} did not answer *IDN? within {timeout:g} s after flashing "
        f"(last: {last}); the upload was verified, but the firmware does not answer"
    )


def _avrdude(programmer: str) -> str:
    """The avrdude program, which must know ``programmer`` (UsageError, exit 2, when it does not)."""
    exe = avrdude.find()
    if programmer not in avrdude.programmers(exe):
        raise UsageError(f"avrdude {avrdude.version(exe)} has no programmer {programmer!r} (avrdude -c '?' lists them)")
    return exe


def flash(
    port: str,
    hex_path: Path | None = None,
    programmer: str = "arduino",
    baud: int = 115200,
    attempts: int | None = 3,
    confirm_timeout: float = 15.0,
    progress: Callable[[str, float], None] | None = None,
) -> Flashed:
    """Build (or take --hex), upload, verify, confirm. Each failure one sentence (see the module)."""
    say = progress or (lambda phase, fraction: None)
    exe = _avrdude(programmer)
    say("building" if hex_path is None else "reading", 0.0)
    fw = firmware(hex_path)
    log_path = fw.hex.with_name(fw.hex.stem + ".avrdude.log")
    try:
        os.close(open_fd(log_path))  # a device, FIFO or symbolic link of that name: refused (files.py)
    except OSError as e:
        raise UsageError(
            f"{log_path}: avrdude's log cannot be written beside the hex ({e.strerror}): "
            f"copy the hex to a folder you can write and give --hex"
        ) from None
    lock = check_port(port)
    try:
        say("uploading", 0.0)
        cmd = avrdude.command(exe, port, fw.hex, programmer, baud, attempts)
        up = avrdude.run(cmd, log_path, port, fw.hex, progress=say)
    finally:
        os.close(lock)
    say("confirming", 0.0)
    reply, serial, took = confirm(port, fw.version, confirm_timeout)
    return Flashed(fw, up, reply, serial, took)


def dry_run(
    hex_path: Path | None = None,
    programmer: str = "arduino",
    baud: int = 115200,
    port: str = "PORT",
    attempts: int | None = 3,
) -> tuple[Firmware, list[str], str]:
    """Everything but the board: build (or read --hex), check avrdude and the programmer; the
    command that would run and avrdude's version. The port is not opened."""
    exe = _avrdude(programmer)
    fw = firmware(hex_path)
    return fw, avrdude.command(exe, port, fw.hex, programmer, baud, attempts), avrdude.version(exe)
