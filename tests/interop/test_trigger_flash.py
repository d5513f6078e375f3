"""`vts trigger flash` against a simulated board: the real avrdude speaks STK500 v1 to a bootloader on a
pty (sim_devices/arduino_bootloader.py), which then runs the image it received in the firmware
emulator, so the version check talks to the firmware just flashed."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import pytest
import serial
from intelhex import IntelHex

from inprocess_cli import run as vts_run
from vts_hw.sim_devices.arduino_bootloader import SimArduinoBoard
from vts_hw.sim_devices.trigger_box import build, firmware_dir

# no skip without avrdude: `make test` installs it (Makefile TEST_DEBS); without it these fail saying so


def vts(*args, env=None):
    """`vts ARGS` in this process (tests/inprocess_cli.py), the variables ``env`` added, nothing
    to read on its standard input: (exit code, stdout, stderr)."""
    p = vts_run(*args, env={**os.environ, **(env or {})})
    return p.returncode, p.stdout, p.stderr


@pytest.fixture(scope="module")
def hex_file(tmp_path_factory):
    """The firmware as built, copied where its avrdude log may be written (not the shared build folder)."""
    build()
    d = tmp_path_factory.mktemp("fw")
    shutil.copy(firmware_dir() / "build" / "trigger_box.hex", d / "trigger_box.hex")
    return d / "trigger_box.hex"


def _hex_bytes(path: Path) -> bytes:
    ih = IntelHex(str(path))
    return ih.tobinstr(start=0)


def _with_version(src: Path, dst: Path, old: bytes, new: bytes) -> Path:
    """A copy of the firmware whose *IDN? version string says ``new`` (same length, checksums right)."""
    data = bytearray(_hex_bytes(src))
    at = data.find(b"," + old + b"\x00")
    assert at > 0
    data[at + 1 : at + 1 + len(new)] = new
    ih = IntelHex()
    ih.frombytes(bytes(data), offset=0)
    ih.write_hex_file(str(dst))
    return dst


def test_flash_builds_uploads_verifies_and_the_flashed_firmware_answers(tmp_path):
    with SimArduinoBoard(workdir=tmp_path / "board") as board:
        rc, out, err = vts("trigger", "flash", "--port", board.port)
        assert rc == 0, err
        built = firmware_dir() / "build" / "trigger_box.hex"
        want = _hex_bytes(built)
        got = board.image()
        # every page written equals the hex; the padding of the last page is erased flash
        assert got[: len(want)] == want and set(got[len(want) :]) <= {0xFF}
        assert board.uploads == 1 and board.app is not None, board.app_error
        assert f"{board.port}: wrote {len(want)} bytes of trigger_box.hex and verified {len(want)}" in out
        assert "firmware 1.1.0 confirmed, serial 0000" in out
        # the *IDN? came to the emulated firmware running the image received (its UART saw it)
        rx = bytes(b.value for b in board.app.uart() if b.direction == "RX")
        assert b"*IDN?\n" in rx
        # avrdude's words went to the log beside the hex, not to the terminal; progress did
        log = built.with_name("trigger_box.avrdude.log").read_text()
        assert f"{len(want)} bytes of flash verified" in log and "Thank you" not in out + err
        assert "building the firmware" in err and "verifying 100 %" in err and "asking the box" in err


def test_flash_of_a_given_hex_and_json(tmp_path, hex_file):
    with SimArduinoBoard(workdir=tmp_path / "board") as board:
        rc, out, err = vts("trigger", "flash", "--port", board.port, "--hex", hex_file, "--json")
        assert rc == 0, err
    import json

    doc = json.loads(out)
    assert doc["version"] == "1.1.0" and doc["identity"] == "VTS,TRIGGERBOX,0000,1.1.0"
    assert doc["written"] == doc["verified"] == len(_hex_bytes(hex_file))
    assert Path(doc["log"]) == hex_file.with_name("trigger_box.avrdude.log")


def test_dry_run_checks_everything_but_touches_no_port(tmp_path, hex_file):
    with SimArduinoBoard(workdir=tmp_path / "board") as board:
        rc, out, err = vts("trigger", "flash", "--port", board.port, "--hex", hex_file, "--dry-run")
        time.sleep(0.2)
        assert board.commands == []
    assert rc == 0, err
    assert f"-c arduino -P {board.port} -b 115200 -D" in out and f"flash:w:{hex_file}:i" in out
    assert "firmware 1.1.0" in out and "nothing was sent" in out


def test_a_silent_bootloader_is_one_sentence_naming_the_port(tmp_path, hex_file):
    with SimArduinoBoard(silent=True, workdir=tmp_path / "board") as board:
        rc, out, err = vts("trigger", "flash", "--port", board.port, "--hex", hex_file, "--attempts", "1")
        assert board.written == {}
    assert rc == 4, err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"vts: the bootloader on {board.port} did not answer to 1 sync attempt(s)")
    assert "nothing was written" in last and "trigger_box.avrdude.log" in last
    assert "Traceback" not in err and "confirmed" not in out


def test_a_verify_mismatch_fails_and_says_so(tmp_path, hex_file):
    with SimArduinoBoard(corrupt_page=3, workdir=tmp_path / "board") as board:
        rc, out, err = vts("trigger", "flash", "--port", board.port, "--hex", hex_file)
    assert rc == 4, err
    last = err.strip().splitlines()[-1]
    was = _hex_bytes(hex_file)[0x1C0]  # page 3 (0x180..0x1ff), its middle byte stored with bit 0 flipped
    assert last.startswith(
        f"vts: verify failed: the flash of the box on {board.port} differs from {hex_file} at byte 0x01c0 "
        f"(the box holds 0x{was ^ 1:02x}, the file 0x{was:02x})"
    )
    assert "flash again" in last and "confirmed" not in out
    assert "verification mismatch" in hex_file.with_name("trigger_box.avrdude.log").read_text()


def test_a_box_answering_another_version_fails(tmp_path, hex_file):
    """The hex says 1.1.9; the board runs the 1.1.0 build after the upload (not what it received)."""
    patched = _with_version(hex_file, tmp_path / "tb-1.1.9.hex", b"1.1.0", b"1.1.9")
    elf = firmware_dir() / "build" / "trigger_box.elf"
    with SimArduinoBoard(runs=elf, workdir=tmp_path / "board") as board:
        rc, out, err = vts("trigger", "flash", "--port", board.port, "--hex", patched)
        assert board.image()[: len(_hex_bytes(patched))] == _hex_bytes(patched)  # written and verified
    assert rc == 4, err
    assert f"vts: the box on {board.port} answers firmware version 1.1.0 after flashing, not 1.1.9 just written" in err


def test_a_missing_port_is_a_device_failure(tmp_path, hex_file):
    rc, out, err = vts("trigger", "flash", "--port", tmp_path / "ttyACM9", "--hex", hex_file)
    assert rc == 4 and f"vts: {tmp_path / 'ttyACM9'} does not exist: is the trigger box plugged in?" in err


def test_a_busy_port_is_named_and_nothing_is_sent(tmp_path, hex_file):
    with SimArduinoBoard(workdir=tmp_path / "board") as board:
        with serial.Serial(board.port, 115200, exclusive=True):
            rc, out, err = vts("trigger", "flash", "--port", board.port, "--hex", hex_file)
        assert board.commands == []
    assert rc == 4 and f"vts: {board.port} is busy: another program has it open and locked" in err


def test_bad_inputs_are_one_sentence_exit_2(tmp_path, hex_file):
    # no avrdude on the PATH
    bare = tmp_path / "bin"
    bare.mkdir()
    rc, _, err = vts("trigger", "flash", "--hex", hex_file, env={"PATH": str(bare)})
    assert rc == 2 and "vts: avrdude is not installed" in err
    # an installed vts-hw: no sources, no --hex
    rc, _, err = vts("trigger", "flash", "--port", "/dev/null", env={"VTS_FIRMWARE_DIR": str(tmp_path)})
    assert rc == 2 and f"no trigger box firmware sources here ({tmp_path} has no Makefile" in err
    assert "--hex FILE" in err
    # a file that is not Intel HEX; a hex that is not the trigger box's firmware
    junk = tmp_path / "junk.hex"
    junk.write_text("hello\n")
    rc, _, err = vts("trigger", "flash", "--hex", junk)
    assert rc == 2 and f"vts: {junk}: not a firmware to flash: cannot be read as Intel HEX" in err
    other = tmp_path / "blink.hex"
    ih = IntelHex()
    ih.frombytes(b"\x0c\x94\x34\x00" * 64, offset=0)
    ih.write_hex_file(str(other))
    rc, _, err = vts("trigger", "flash", "--hex", other)
    assert rc == 2 and f"vts: {other}: not a trigger box firmware" in err
