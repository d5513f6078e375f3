"""The trigger box, simulated by running its real firmware in an AVR emulator.

:class:`SimTriggerBox` builds the firmware and the harness (``make -C firmware``, which
does nothing when they are up to date), starts ``firmware/build/tbsim`` with
``firmware/build/trigger_box.elf`` and waits for its serial pseudo-terminal. A driver opens
:attr:`SimTriggerBox.port` with pyserial exactly as it would open the USB serial port of a
real box (115200 baud 8N1)::

    with SimTriggerBox() as box:
        with serial.Serial(box.port, 115200, timeout=1) as s:
            s.write(b"*IDN?\\n")
            print(s.readline())            # b'VTS,TRIGGERBOX,0000,1.1.0\\n'
        print(box.edges("OC1A")[:4])       # what the output pins did, in emulated cycles

The emulator runs in real time (``speed=1``): emulated cycles are kept in step with the
wall clock. ``speed=10`` runs ten emulated seconds per wall second (for long periods in
tests); ``speed=0`` runs as fast as the host can. Whatever the speed, timing inside the
emulation is exact and deterministic in cycles (16 per microsecond).

The harness logs each change of the output pins (``OC1A``: square wave on PB1, ``CH1``:
VTS start pulse on PD6, ``CH2``: SPECT start pulse on PD7) with its emulated cycle count,
and every serial byte (``RX`` host to device, ``TX`` device to host). :meth:`unplug`
simulates the USB serial vanishing (the harness exits and its pty closes);
:meth:`replug` powers up a fresh box on a new pty. See
``docs/decisions/0009-trigger-box-firmware.md``.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

from vts_hw.files import open_writable
from vts_hw.lifeline import child_options

__all__ = ["SimTriggerBox", "Edge", "UartByte", "F_CPU", "PINS", "firmware_dir", "build"]

F_CPU = 16_000_000
PINS = ("OC1A", "CH1", "CH2")


def firmware_dir() -> Path:
    """``firmware/`` of the checkout (``$VTS_FIRMWARE_DIR`` overrides it)."""
    env = os.environ.get("VTS_FIRMWARE_DIR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[1] / "firmware"


class Edge(NamedTuple):
    """A change of an output pin: its name, the new level and the emulated cycle."""

    pin: str
    value: int
    cycle: int

    @property
    def seconds(self) -> float:
        """The cycle as emulated seconds since reset (16 MHz)."""
        return self.cycle / F_CPU


class UartByte(NamedTuple):
    """A serial byte: ``"RX"`` (host to device, when handed to the UART) or ``"TX"``
    (device to host, when the firmware wrote it), its value and the emulated cycle."""

    direction: str
    value: int
    cycle: int


def build(quiet: bool = True) -> tuple[Path, Path]:
    """``make -C firmware``; returns (harness, firmware ELF). Raises RuntimeError with
    make's output if the build fails. Concurrent callers are serialised by a lock file."""
    fw = firmware_dir()
    if not (fw / "Makefile").is_file():
        raise RuntimeError(
            f"trigger box firmware sources not found in {fw} (an installed vts-hw has none: "
            "set VTS_FIRMWARE_DIR to the firmware/ folder of a checkout)"
        )
    lock_dir = Path(tempfile.gettempdir())
    # in the temporary folder everyone writes: never emptied, never opened through a link (files.py)
    with open_writable(lock_dir / f"vts-trigger-box-build-{os.getuid()}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        proc = subprocess.run(
            ["make", "-C", str(fw)] + (["--quiet"] if quiet else []),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            **child_options(),
        )
    if proc.returncode != 0:
        raise RuntimeError(f"building the trigger box firmware failed:\n{proc.stdout}")
    return fw / "build" / "tbsim", fw / "build" / "trigger_box.elf"


class SimTriggerBox:
    """The firmware in the emulator behind a pty. Use as a context manager, or call
    :meth:`start` and :meth:`stop`."""

    def __init__(
        self,
        speed: float = 1.0,
        workdir: str | os.PathLike | None = None,
        log_uart: bool = True,
        startup_timeout: float = 20.0,
        firmware: str = "trigger_box",
        elf: str | os.PathLike | None = None,
    ):
        if speed < 0:
            raise ValueError("speed must be >= 0 (0 = as fast as possible)")
        self.speed = speed
        self.firmware = firmware  # build/<firmware>.elf; "trigger_box_late" for tests
        self.elf = Path(elf) if elf is not None else None  # any other image (a flashed one) instead
        self.log_uart = log_uart
        self.startup_timeout = startup_timeout
        self._own_dir = workdir is None
        self.dir = Path(workdir) if workdir is not None else None
        self.proc: subprocess.Popen | None = None
        self.port: str | None = None
        self.boots = 0
        self._edges: list[Edge] = []
        self._uart: list[UartByte] = []
        self._log_pos = 0
        self._log_path: Path | None = None
        self._anchor: tuple[int, float, float] | None = None  # (cycle, host epoch s, speed)

    # ------------------------------------------------------------------ life cycle
    def start(self) -> SimTriggerBox:
        harness, elf = build()
        elf = self.elf or elf.with_name(f"{self.firmware}.elf")
        if not elf.is_file():
            raise RuntimeError(f"no firmware {elf}")
        if self.dir is None:
            self.dir = Path(tempfile.mkdtemp(prefix="vts-trigger-box-"))
        self.dir.mkdir(parents=True, exist_ok=True)
        self.boots += 1
        tag = f"boot{self.boots}"
        self._log_path = self.dir / f"{tag}.edges.log"
        self._edges, self._uart, self._log_pos = [], [], 0
        self._anchor = None
        pty_file = self.dir / f"{tag}.pty"
        self._status_path = self.dir / f"{tag}.status"
        cmd = [
            str(harness),
            "--edges",
            str(self._log_path),
            "--pty-file",
            str(pty_file),
            "--status",
            str(self._status_path),
            "--speed",
            repr(float(self.speed)),
        ]
        if not self.log_uart:
            cmd.append("--no-uart-log")
        cmd.append(str(elf))
        self._stdout = open_writable(self.dir / f"{tag}.out", "w")
        # ends with the thread that starts it (the rig's, or a test's), kill -9 of the rig included:
        # SIGTERM, on which the harness flushes its log and removes its pty file
        self.proc = subprocess.Popen(
            cmd,
            stdout=self._stdout,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            **child_options(signal.SIGTERM),
        )
        deadline = time.monotonic() + self.startup_timeout
        while not pty_file.exists():
            if self.proc.poll() is not None:
                out = (self.dir / f"{tag}.out").read_text(errors="replace")
                raise RuntimeError(f"the trigger box emulator exited at start ({self.proc.returncode}): {out.strip()}")
            if time.monotonic() > deadline:
                self._kill()
                raise RuntimeError("the trigger box emulator did not open its pty in time")
            time.sleep(0.01)
        self.port = pty_file.read_text().strip()
        return self

    def stop(self) -> None:
        """Stop the emulator (its logs stay readable until the object is dropped)."""
        self._terminate()
        if self._own_dir and self.dir is not None:
            self._read_log()
            shutil.rmtree(self.dir, ignore_errors=True)
            self.dir = None

    def unplug(self) -> None:
        """The USB serial vanishes: the emulator exits and the pty goes away, so an open
        port sees a hang-up (pyserial raises SerialException on the next read or write)."""
        self._terminate()

    def replug(self) -> str:
        """Plug a box in again: a fresh power-up (device time restarts at 0, settings at
        their defaults) on a new pty. Returns the new :attr:`port`."""
        self._terminate()
        self.start()
        if self.port is None:  # start() makes it (or raises)
            raise RuntimeError("the simulated trigger box started without a port")
        return self.port

    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def _terminate(self) -> None:
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._kill()
        self._read_log()
        self._stdout.close()
        self.proc = None
        self.port = None

    def _kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def __enter__(self) -> SimTriggerBox:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def __del__(self):  # pragma: no cover - best effort
        try:
            self._kill()
        except Exception:
            pass

    # ------------------------------------------------------------------ observation
    def _read_log(self) -> None:
        if self._log_path is None or not self._log_path.exists():
            return
        with open(self._log_path, "rb") as f:
            f.seek(self._log_pos)
            data = f.read()
        end = data.rfind(b"\n") + 1  # only whole lines; the rest comes next time
        self._log_pos += end
        for line in data[:end].decode("ascii", "replace").splitlines():
            if line.startswith("# t0 "):  # the pacing's host-time anchor (tbsim.c)
                cycle, realtime, _mono, speed = line.split()[2:6]
                self._anchor = (int(cycle), float(realtime), float(speed))
            if not line or line.startswith("#"):
                continue
            cycle, what, value = line.split()
            if what in ("RX", "TX"):
                self._uart.append(UartByte(what, int(value, 16), int(cycle)))
            else:
                self._edges.append(Edge(what, int(value), int(cycle)))

    def edges(self, pin: str | None = None) -> list[Edge]:
        """Every output pin change so far (of one pin if given), oldest first."""
        self._read_log()
        if pin is None:
            return list(self._edges)
        return [e for e in self._edges if e.pin == pin]

    def host_time(self, cycle: int) -> float:
        """The host time (UTC epoch seconds) at which the emulation is paced to reach ``cycle``:
        ``t0 + (cycle - c0) / F_CPU / speed`` from the anchor the harness logs as it starts.
        The emulation keeps to it within ~0.2 ms while the host gives it the CPU (it lags
        and catches up after a stall). Needs ``speed > 0``."""
        if self._anchor is None:
            deadline = time.monotonic() + 5.0
            while self._anchor is None and time.monotonic() < deadline:
                self._read_log()
                if self._anchor is None:
                    time.sleep(0.002)
        if self._anchor is None:
            raise RuntimeError("the trigger box emulator has logged no host-time anchor")
        c0, t0, speed = self._anchor
        if speed <= 0:
            raise RuntimeError("emulated cycles have no host time at speed 0 (as fast as possible)")
        return t0 + (cycle - c0) / F_CPU / speed

    def uart(self) -> list[UartByte]:
        """Every serial byte so far, oldest first (empty with ``log_uart=False``)."""
        self._read_log()
        return list(self._uart)

    def cycles_now(self) -> int:
        """The emulated cycle count, as the harness last reported it (every 5 ms)."""
        try:
            text = self._status_path.read_text().strip()
            return int(text) if text else 0
        except (OSError, ValueError, AttributeError):
            return 0

    def wait_cycles(self, cycles: int, timeout: float | None = None) -> int:
        """Wait until ``cycles`` more emulated cycles have passed; returns the count.
        Waiting on emulated time keeps tests right on a slow host."""
        return self.wait_until(self.cycles_now() + int(cycles), timeout)

    def wait_until(self, cycle: int, timeout: float | None = None) -> int:
        """Wait until the emulation reaches ``cycle``; returns the count then."""
        if timeout is None:
            rate = F_CPU * (self.speed if self.speed > 0 else 1.0)
            timeout = 30.0 + max(0, cycle - self.cycles_now()) / rate * 4
        deadline = time.monotonic() + timeout
        while True:
            now = self.cycles_now()
            if now >= cycle:
                return now
            if not self.running():
                raise RuntimeError("the trigger box emulator is not running")
            if time.monotonic() > deadline:
                raise TimeoutError(f"emulation did not reach cycle {cycle} (at {now})")
            time.sleep(0.002)
