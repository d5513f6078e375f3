"""An Arduino board with its bootloader, simulated: STK500 v1 on a pty, then the flashed firmware.

:class:`SimArduinoBoard` opens a pseudo-terminal that avrdude (``-c arduino``) or anything else
opens as it would an Uno's USB serial port (:attr:`port`). Behind it the board's bootloader speaks
STK500 version 1 as Atmel's AVR061 ("STK500 Communication Protocol") describes it and an Arduino
bootloader (optiboot) implements it: every command is a command byte, its fixed arguments and
``Sync_CRC_EOP`` (0x20); the answer is ``Resp_STK_INSYNC`` (0x14), any data, ``Resp_STK_OK``
(0x10); a command not ending in 0x20 gets ``Resp_STK_NOSYNC`` (0x15). Flash addresses
(``Cmnd_STK_LOAD_ADDRESS``) are in words; ``Cmnd_STK_PROG_PAGE`` writes a page (128 bytes on the
ATmega328P), ``Cmnd_STK_READ_PAGE`` reads one back (avrdude's verify).

``Cmnd_STK_LEAVE_PROGMODE`` ends the upload and starts the application, as the real bootloader
does (a watchdog reset into the new firmware): the flash image received is written as Intel HEX
(:attr:`received_hex`), turned into an ELF (avr-objcopy) and run in the project's emulator
(:class:`~vts_hw.sim_devices.trigger_box.SimTriggerBox`), and the pty is bridged to the emulator's,
so whoever opens :attr:`port` next talks to the firmware just flashed.

Faults: ``silent=True`` (no bootloader answers: a wrong port or baud, a board without one),
``corrupt_page=N`` (the N-th page written is stored with one byte flipped: a failing flash cell,
so avrdude's verify must find it), ``runs=ELF`` (after the upload the board runs that ELF, not
what it received: the version check must notice).
"""

from __future__ import annotations

import os
import pty
import select
import subprocess
import tempfile
import threading
import time
import tty
from pathlib import Path

from vts_hw.lifeline import child_options
from vts_hw.sim_devices.trigger_box import SimTriggerBox

INSYNC, OK, NOSYNC, EOP = 0x14, 0x10, 0x15, 0x20
SIGNATURE_M328P = bytes([0x1E, 0x95, 0x0F])
FLASH_SIZE, PAGE_SIZE = 32 * 1024, 128
#: bytes of arguments after the command byte, before EOP (AVR061)
ARGS = {
    0x30: 0,
    0x31: 0,
    0x40: 2,
    0x41: 1,
    0x42: 20,
    0x50: 0,
    0x51: 0,
    0x52: 0,
    0x53: 0,
    0x55: 2,
    0x56: 4,
    0x60: 2,
    0x61: 3,
    0x62: 2,
    0x63: 1,
    0x65: 3,
    0x70: 0,
    0x71: 0,
    0x72: 0,
    0x73: 0,
    0x75: 0,
    0x76: 0,
    0x77: 0,
    0x78: 1,
}
#: what a read command answers with, before OK
PARAMETERS = {0x80: 0x02, 0x81: 0x08, 0x82: 0x00}  # HW_VER, SW_MAJOR, SW_MINOR (optiboot 8.0)
FUSES = {(0x50, 0x00): 0xFF, (0x58, 0x08): 0xDE, (0x50, 0x08): 0xFD, (0x58, 0x00): 0xCF}  # lfuse hfuse efuse lock


class SimArduinoBoard:
    """The bootloader on a pty, then the flashed firmware in the emulator. A context manager."""

    def __init__(
        self,
        *,
        silent: bool = False,
        corrupt_page: int | None = None,
        runs: str | os.PathLike | None = None,
        workdir: str | os.PathLike | None = None,
        speed: float = 1.0,
    ):
        self.silent = silent
        self.corrupt_page = corrupt_page
        self.runs = Path(runs) if runs is not None else None
        self.speed = speed
        self.dir = Path(workdir or tempfile.mkdtemp(prefix="vts-arduino-"))
        self.dir.mkdir(parents=True, exist_ok=True)
        self.flash = bytearray(b"\xff" * FLASH_SIZE)
        self.written: dict[int, int] = {}  # byte address -> length, every page written
        self.commands: list[int] = []  # every command byte received, in order
        self.uploads = 0  # LEAVE_PROGMODE after at least one page
        self.received_hex: Path | None = None
        self.app: SimTriggerBox | None = None  # the SimTriggerBox running the flashed image
        self.app_error: str | None = None
        self._master = self._slave = -1
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._addr = 0
        self._buf = bytearray()

    # -- life cycle ---------------------------------------------------------------------------
    def start(self) -> SimArduinoBoard:
        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)  # the line is raw until the program that opens it sets its own mode
        self.port = os.ttyname(self._slave)  # kept open here: the master never sees EIO between openers
        self._thread = threading.Thread(target=self._serve, name="sim-arduino", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        if self.app is not None:
            self.app.stop()
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1

    def __enter__(self) -> SimArduinoBoard:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- the line -----------------------------------------------------------------------------
    def _read(self, n: int, timeout: float = 1.0) -> bytes | None:
        """n bytes from the host, or None when they do not come within ``timeout``."""
        deadline = time.monotonic() + timeout
        while len(self._buf) < n:
            left = deadline - time.monotonic()
            if left <= 0 or self._stop.is_set():
                return None
            r, _, _ = select.select([self._master], [], [], min(left, 0.1))
            if r:
                self._buf += os.read(self._master, 4096)
        out, self._buf = bytes(self._buf[:n]), self._buf[n:]
        return out

    def _send(self, data: bytes) -> None:
        os.write(self._master, data)

    def _serve(self) -> None:
        while not self._stop.is_set():
            if self.app is not None or self.app_error is not None:
                self._bridge()
                return
            head = self._read(1, 0.1)
            if head is None or self.silent:
                continue
            self._command(head[0])

    def _command(self, cmd: int) -> None:
        self.commands.append(cmd)
        if cmd in (0x64, 0x74):  # PROG_PAGE / READ_PAGE: size (big-endian), memory type
            args = self._read(3)
            if args is None:
                return
            size = args[0] << 8 | args[1]
            data = self._read(size) if cmd == 0x64 else b""
            if data is None or self._read(1) != bytes([EOP]):
                self._send(bytes([NOSYNC]))
                return
            self._page(cmd, size, chr(args[2]), data)
            return
        if cmd == 0x45:  # SET_DEVICE_EXT: a length byte counts itself
            n = self._read(1)
            args = n + (self._read(max(n[0] - 1, 0)) or b"") if n else None
        elif cmd in ARGS:
            args = self._read(ARGS[cmd])
        else:  # not a command: the real bootloader would reset
            self._send(bytes([NOSYNC]))
            return
        if args is None or self._read(1) != bytes([EOP]):
            self._send(bytes([NOSYNC]))
            return
        reply = b""
        if cmd == 0x31:
            reply = b"AVR STK"
        elif cmd == 0x41:
            reply = bytes([PARAMETERS.get(args[0], 0x03)])
        elif cmd == 0x55:
            self._addr = (args[0] | args[1] << 8) * 2  # words to bytes (flash)
        elif cmd == 0x56:
            reply = bytes([FUSES.get((args[0], args[1]), 0x00)])
        elif cmd == 0x75:
            reply = SIGNATURE_M328P
        elif cmd in (0x71, 0x73, 0x76, 0x78):
            reply = b"\x00"
        elif cmd in (0x70, 0x72):
            reply = b"\x00\x00"
        elif cmd == 0x77:
            reply = b"\x00\x00\x00"
        self._send(bytes([INSYNC]) + reply + bytes([OK]))
        if cmd == 0x51 and self.written:  # LEAVE_PROGMODE after an upload: the new firmware starts
            self.uploads += 1
            self._start_app()

    def _page(self, cmd: int, size: int, memory: str, data: bytes) -> None:
        addr = self._addr
        if memory != "F" or addr + size > FLASH_SIZE:  # only the flash is kept (nothing writes EEPROM here)
            self._send(bytes([INSYNC]) + (b"\xff" * size if cmd == 0x74 else b"") + bytes([OK]))
            return
        if cmd == 0x64:
            page = bytearray(data)
            if self.corrupt_page is not None and len(self.written) == self.corrupt_page and page:
                page[len(page) // 2] ^= 0x01
            self.flash[addr : addr + size] = page
            self.written[addr] = size
            self._send(bytes([INSYNC, OK]))
        else:
            self._send(bytes([INSYNC]) + bytes(self.flash[addr : addr + size]) + bytes([OK]))
        self._addr = addr + size

    # -- after the upload: the firmware runs ----------------------------------------------------
    def image(self) -> bytes:
        """The flash as written, up to the last page written (0xFF between pages)."""
        end = max((a + n for a, n in self.written.items()), default=0)
        return bytes(self.flash[:end])

    def _start_app(self) -> None:
        from intelhex import IntelHex

        try:
            ih = IntelHex()
            ih.frombytes(self.image(), offset=0)
            self.received_hex = self.dir / f"received{self.uploads}.hex"
            ih.write_hex_file(str(self.received_hex))
            elf = self.runs
            if elf is None:
                elf = self.received_hex.with_suffix(".elf")
                subprocess.run(
                    [
                        "avr-objcopy",
                        "-I",
                        "ihex",
                        "-O",
                        "elf32-avr",
                        "--rename-section",
                        ".sec1=.text,contents,alloc,load,readonly,code",
                        str(self.received_hex),
                        str(elf),
                    ],
                    check=True,
                    capture_output=True,
                    **child_options(),
                )
            self.app = SimTriggerBox(speed=self.speed, workdir=self.dir / f"app{self.uploads}", elf=elf).start()
        except Exception as e:  # the test reads it: a board whose firmware did not start answers nothing
            self.app_error = f"{type(e).__name__}: {e}"

    def _bridge(self) -> None:
        """Copy bytes both ways between our pty and the emulator's until stopped."""
        if self.app is None or self.app.port is None:
            while not self._stop.wait(0.1):  # nothing runs: input is dropped, as a dead board would
                self._read(4096, 0)
            return
        app = os.open(self.app.port, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(app)
        self._buf.clear()  # what came while the firmware was starting went to the bootloader
        try:
            while not self._stop.is_set():
                r, _, _ = select.select([self._master, app], [], [], 0.1)
                if self._master in r:
                    os.write(app, os.read(self._master, 4096))
                if app in r:
                    try:
                        data = os.read(app, 4096)
                    except OSError:  # the emulator went away
                        return
                    os.write(self._master, data)
        finally:
            os.close(app)
