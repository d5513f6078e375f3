"""avrdude, the AVR uploader, run as a program: its command line, its progress, what its failures mean.

The trigger box is an ATmega328P board (Arduino Uno/Nano class) with an Arduino bootloader
(optiboot), which speaks STK500 version 1 over the USB serial line: avrdude's ``-c arduino``
programmer. avrdude resets the board (DTR/RTS), syncs with the bootloader, writes the flash page
by page, reads it back to verify (unless ``-V``), and leaves programming mode, which starts the
new firmware. Its whole output goes to a log file; what it says while writing and reading is
turned into progress (avrdude draws 50 ``#`` per bar), and a failure is classified from its
words into one sentence (docs/decisions/0070-trigger-flash.md).

Known to work with avrdude 7.1 (Debian 12). ``-x attempts=N`` (the arduino programmer's number
of sync attempts, 10 by default, about 5.6 s each when nothing answers) is passed for ``arduino``.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from vts_hw.errors import DeviceError, UsageError
from vts_hw.files import open_writable
from vts_hw.lifeline import child_options

#: the trigger box's MCU as avrdude names it (firmware/Makefile: MCU := atmega328p)
PART = "m328p"
BAR_WIDTH = 50  # avrdude's progress bar: 50 '#' from 0 to 100 %
ASK_S = 10.0  # how long avrdude may take to say its version or its programmers


class AvrdudeMissing(UsageError):
    """avrdude is not installed (exit 2: the machine is not set up)."""


class AvrdudeBroken(UsageError):
    """avrdude is there but does not answer a question it answers at once (exit 2: the machine is not set up)."""


class UploadFailed(DeviceError):
    """avrdude could not write or verify the board (exit 4). ``kind`` says which failure."""

    def __init__(self, text: str, kind: str, output: str = ""):
        super().__init__(text)
        self.kind = kind
        self.output = output


@dataclass(frozen=True)
class Upload:
    """What one avrdude run did: its command, the bytes written and verified, the log file."""

    command: tuple[str, ...]
    written: int | None
    verified: int | None
    log: Path
    version: str


def find() -> str:
    """The avrdude program; AvrdudeMissing (one sentence) when it is not installed."""
    path = shutil.which("avrdude")
    if path is None:
        raise AvrdudeMissing(
            "avrdude is not installed (Debian: apt-get install avrdude; `make test` installs "
            "it): it uploads the firmware through the board's bootloader"
        )
    return path


def _ask(avrdude: str, *args: str) -> str:
    """What ``avrdude ARGS`` prints (it answers such questions at once); AvrdudeBroken (one
    sentence, exit 2) when it hangs or cannot be started."""
    try:
        out = subprocess.run([avrdude, *args], capture_output=True, text=True, timeout=ASK_S, **child_options())
    except subprocess.TimeoutExpired:
        raise AvrdudeBroken(
            f"{avrdude} {' '.join(args)} did not answer within {ASK_S:g} s: is this avrdude "
            "working (Debian: apt-get install --reinstall avrdude)?"
        ) from None
    except OSError as exc:
        raise AvrdudeBroken(f"{avrdude} could not be started ({exc.strerror or exc})") from None
    return out.stdout + out.stderr


def version(avrdude: str) -> str:
    """avrdude's version, as it prints it (``7.1``); ``unknown`` when it says none."""
    m = re.search(r"avrdude version ([\w.+~-]+)", _ask(avrdude, "-?"))
    return m.group(1).rstrip(",") if m else "unknown"


def programmers(avrdude: str) -> set[str]:
    """The programmer ids this avrdude knows (``avrdude -c '?'``)."""
    return set(re.findall(r"^\s+(\S+)\s+=", _ask(avrdude, "-c", "?"), re.M))


def command(
    avrdude: str, port: str, hex_path: Path, programmer: str, baud: int, attempts: int | None = None
) -> list[str]:
    """The upload: write the flash from ``hex_path`` (Intel HEX), verify it (avrdude's default).
    ``-D``: no chip erase first (a bootloader cannot erase the chip: it erases each page it writes)."""
    cmd = [avrdude, "-p", PART, "-c", programmer, "-P", port, "-b", str(baud), "-D"]
    if attempts is not None and programmer == "arduino":
        cmd += ["-x", f"attempts={attempts}"]
    return cmd + ["-U", f"flash:w:{hex_path}:i"]


def run(
    cmd: list[str],
    log_path: Path,
    port: str,
    hex_path: Path,
    progress: Callable[[str, float], None] | None = None,
    timeout: float = 300.0,
) -> Upload:
    """Run the upload, its whole output into ``log_path``; ``progress(phase, fraction)`` with
    phase ``writing`` or ``verifying`` as avrdude draws its bars. UploadFailed names the port or
    the file, and what went wrong; the log keeps every word avrdude said."""
    phase, hashes = None, 0
    text = bytearray()
    with open_writable(log_path, "wb") as log:  # never a device, FIFO or symbolic link (files.py)
        log.write(("$ " + " ".join(cmd) + "\n").encode())
        log.flush()
        # killed with this command, however it ends (kill -9 too): never left holding the port
        proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, **child_options()
        )
        assert proc.stdout is not None
        try:
            while True:
                chunk = os.read(proc.stdout.fileno(), 4096)
                if not chunk:
                    break
                log.write(chunk)
                log.flush()
                text += chunk
                if progress is None:
                    continue
                for token in re.finditer(rb"(Writing|Reading) \||#", chunk):
                    if token.group(1):
                        phase = "writing" if token.group(1) == b"Writing" else "verifying"
                        hashes = 0
                    elif phase is not None:
                        hashes += 1
                        if hashes % 5 == 0:
                            progress(phase, min(1.0, hashes / BAR_WIDTH))
            rc = proc.wait(timeout=timeout)
        except BaseException:
            proc.kill()
            proc.wait()
            raise
    out = text.decode("utf-8", "replace")
    if rc != 0:
        raise classify(out, rc, port, hex_path, log_path)
    written = _count(out, r"(\d+) bytes of flash written")
    verified = _count(out, r"(\d+) bytes of flash verified")
    if verified is None:  # never "verified" unless avrdude said so
        raise UploadFailed(
            f"avrdude wrote {hex_path.name} to {port} but did not say it verified it (see {log_path})", "verify", out
        )
    return Upload(tuple(cmd), written, verified, log_path, version(cmd[0]))


def _count(out: str, pattern: str) -> int | None:
    found = re.findall(pattern, out)
    return int(found[-1]) if found else None


def classify(out: str, rc: int, port: str, hex_path: Path, log_path: Path) -> UploadFailed:
    """avrdude's failure in one sentence naming the port or the file."""
    see = f"avrdude's output is in {log_path}"
    if re.search(r"verification (?:error|mismatch)", out):
        # avrdude 7: "device 0x62 != input 0x63 at addr 0x01c0"; 6: "first mismatch at byte 0x01c0"
        m = re.search(r"device (0x[0-9a-fA-F]+) != input (0x[0-9a-fA-F]+) at addr (0x[0-9a-fA-F]+)", out)
        m6 = re.search(r"first mismatch at byte (0x[0-9a-fA-F]+)", out)
        at = (
            f" at byte 0x{int(m.group(3), 16):04x} (the box holds {m.group(1)}, the file {m.group(2)})"
            if m
            else f" at byte 0x{int(m6.group(1), 16):04x}"
            if m6
            else ""
        )
        return UploadFailed(
            f"verify failed: the flash of the box on {port} differs from {hex_path}{at} after "
            f"writing it; the box holds a damaged firmware now: flash again ({see})",
            "verify",
            out,
        )
    if re.search(r"can't open device|cannot open port|ser_open\(\)|No such file or directory", out):
        return UploadFailed(f"avrdude could not open {port} ({see})", "port", out)
    if re.search(r"not in sync|programmer is not responding|unable to open programmer", out):
        tries = re.findall(r"attempt \d+ of (\d+)", out)
        n = f" to {tries[-1]} sync attempt(s)" if tries else ""
        return UploadFailed(
            f"the bootloader on {port} did not answer{n} (is it the trigger box, and its "
            f"bootloader's baud rate: 115200 for an Uno's optiboot, 57600 for an older Nano's?): "
            f"nothing was written ({see})",
            "silent",
            out,
        )
    if re.search(r"[Ss]ignature", out) and re.search(
        r"expected signature|[Dd]evice signature.*(?:invalid|mismatch)", out
    ):
        return UploadFailed(
            f"the board on {port} is not an ATmega328P (its signature differs): nothing was written ({see})",
            "signature",
            out,
        )
    if re.search(r"(?:can't|cannot|unable to) (?:open|read).*" + re.escape(hex_path.name), out):
        return UploadFailed(f"avrdude could not read {hex_path} ({see})", "file", out)
    last = [ln.strip() for ln in out.splitlines() if "error" in ln.lower()]
    return UploadFailed(
        f"avrdude failed on {port} (exit {rc}: {last[-1] if last else 'no error line'}; {see})", "other", out
    )
