"""VTSLM list-mode files: write -> read round trips, the registry, and every kind of bad file
answered by one line that names the file (docs/listmode-format.md)."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from vts_hw.errors import DataError
from vts_hw.spect.listmode import (
    ListMode,
    VtslmWriter,
    list_readers,
    read_listmode,
    read_vtslm,
    reader_for,
    vtslm,
    write_vtslm,
)

START = 1_795_000_000.123456


def make_file(path: Path, seed: int = 0, n_events: int = 5000, **header) -> dict:
    """A small valid file written in several blocks per kind; returns what went in."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0, 10.0, n_events))
    z = rng.normal(12.5, 4.0, n_events).astype(np.float32)
    u = rng.normal(-3.0, 30.0, n_events)
    head = rng.integers(0, 2, n_events).astype(np.uint8)
    marks = np.arange(0, 10.0, 0.01)
    frames = np.arange(0, 10.0, 0.1)
    angles = np.repeat([0.0, 6.0], 50)
    gate = np.where((np.arange(20000) // 1000) % 2 == 0, 0.0, 5.0) + rng.normal(0, 0.02, 20000)
    kw = dict(start_time=START, duration_s=10.0, gate_rate_hz=2000.0, dead_time_recorded=True, scanner="test scanner")
    kw.update(header)
    with VtslmWriter(path, **kw) as w:
        for part in np.array_split(np.arange(n_events), 3):
            w.events(t[part], z[part], u[part], head[part])
        w.timing_marks(marks[:500])
        w.gate(gate[:7000])
        w.timing_marks(marks[500:])
        w.frames(frames, np.arange(frames.size), angles)
        w.gate(gate[7000:])
        w.dead([4.0, 8.0], [5.5, 9.0])
    return dict(t=t, z=z, u=u, head=head, marks=marks, frames=frames, angles=angles, gate=gate)


@pytest.fixture()
def good(tmp_path):
    path = tmp_path / "scan.vtslm"
    data = make_file(path)
    return path, data


# --------------------------------------------------------------------------------- round trip


def test_write_read_round_trip(good):
    path, d = good
    lm = read_listmode(path)
    assert isinstance(lm, ListMode) and lm.format == "vtslm" and lm.source == path
    assert lm.start_time == START and lm.duration_s == 10.0
    assert lm.n_events == d["t"].size
    assert np.max(np.abs(lm.t - d["t"])) <= 0.6e-9  # stored to the nanosecond
    assert np.array_equal(lm.z, d["z"])  # float32 as written
    assert np.max(np.abs(lm.u - d["u"])) <= 0.05 + 1e-4  # 0.1 mm steps
    assert np.array_equal(lm.head, d["head"])
    assert np.allclose(lm.timing_marks, d["marks"], atol=1e-9)
    assert np.allclose(lm.frame_starts, d["frames"], atol=1e-9)
    assert np.array_equal(lm.frame_angles, d["angles"])
    assert lm.gate_t.size == d["gate"].size
    assert np.allclose(lm.gate_t[:3], [0.0, 0.0005, 0.001]) and lm.gate_t[-1] == pytest.approx(9.9995)
    vpc = lm.header["gate_volts_per_count"]
    assert np.max(np.abs(lm.gate_v - d["gate"])) <= vpc / 2 + 1e-6
    assert lm.dead.tolist() == [[4.0, 5.5], [8.0, 9.0]]
    assert lm.header["scanner"] == "test scanner"


def test_a_read_file_written_again_is_the_same_file(good, tmp_path):
    path, _ = good
    lm = read_vtslm(path)
    again = write_vtslm(tmp_path / "again.vtslm", lm)
    lm2 = read_vtslm(again)
    for name in ("t", "z", "u", "head", "timing_marks", "frame_starts", "frame_angles", "gate_t", "gate_v"):
        assert np.array_equal(getattr(lm, name), getattr(lm2, name)), name
    assert np.array_equal(lm.dead, lm2.dead)
    assert lm2.header == lm.header
    # one block per kind now, so a different layout but the same content
    assert again.stat().st_size < path.stat().st_size


def test_no_dead_time_records_means_none_not_empty(tmp_path):
    path = tmp_path / "nodead.vtslm"
    with VtslmWriter(path, start_time=1.0, duration_s=1.0, gate_rate_hz=100) as w:
        w.events([0.1, 0.2], [1, 2], [0, 0], [0, 1])
    lm = read_vtslm(path)
    assert lm.dead is None and lm.n_events == 2 and lm.gate_v.size == 0


def test_blocks_of_an_unknown_kind_are_skipped(good, tmp_path):
    path, d = good
    raw = bytearray(path.read_bytes())
    extra = vtslm.BLOCK.pack(b"XTRA", 3, 5, 0) + bytes(15)
    end = raw.rfind(b"END ")
    newer = tmp_path / "newer.vtslm"
    newer.write_bytes(bytes(raw[:end]) + extra + bytes(raw[end:]))
    assert read_vtslm(newer).n_events == d["t"].size


# --------------------------------------------------------------------------------- registry


def test_the_reader_is_chosen_by_content_then_by_suffix(good, tmp_path):
    path, _ = good
    renamed = tmp_path / "scan.dat"
    renamed.write_bytes(path.read_bytes())
    assert reader_for(renamed).name == "vtslm"
    assert read_listmode(renamed).n_events == read_listmode(path).n_events
    assert "vtslm" in [r.name for r in list_readers()]
    assert read_listmode(path, fmt="vtslm").n_events > 0


# --------------------------------------------------------------------------------- bad files


def one_line_error(path: Path, match: str, fmt: str | None = None) -> str:
    with pytest.raises(DataError) as e:
        read_listmode(path, fmt=fmt)
    msg = str(e.value)
    assert "\n" not in msg, msg
    assert msg.startswith(f"{path}: "), msg
    assert match in msg, msg
    return msg


def with_header(good_path: Path, out: Path, change) -> Path:
    raw = good_path.read_bytes()
    magic, major, minor, length = vtslm.PREAMBLE.unpack_from(raw)
    header = json.loads(raw[16 : 16 + length])
    change(header)
    text = json.dumps(header).encode()
    text += b" " * (-(16 + len(text)) % 8)
    out.write_bytes(vtslm.PREAMBLE.pack(magic, major, minor, len(text)) + text + raw[16 + length :])
    return out


def test_missing_file(tmp_path):
    one_line_error(tmp_path / "nowhere.vtslm", "no such file")


def test_a_directory_is_not_a_file(tmp_path):
    d = tmp_path / "dir.vtslm"
    d.mkdir()
    one_line_error(d, "not a file")


def test_empty_and_short_files_are_truncated(tmp_path):
    p = tmp_path / "empty.vtslm"
    p.write_bytes(b"")
    one_line_error(p, "truncated")
    p.write_bytes(vtslm.MAGIC + b"\x01")
    one_line_error(p, "truncated: 9 bytes")


def test_wrong_magic(good, tmp_path):
    path, _ = good
    p = tmp_path / "other.vtslm"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + path.read_bytes()[8:])
    one_line_error(p, "not a VTSLM list-mode file")


def test_not_a_list_mode_file_of_any_known_format(tmp_path):
    p = tmp_path / "notes.txt"
    p.write_text("hello\n")
    one_line_error(p, "not a list-mode file of a known format")
    one_line_error(p, "unknown list-mode format 'siemens'", fmt="siemens")


def test_a_later_major_version(good, tmp_path):
    path, _ = good
    raw = bytearray(path.read_bytes())
    struct.pack_into("<H", raw, 8, 2)
    p = tmp_path / "v2.vtslm"
    p.write_bytes(bytes(raw))
    one_line_error(p, "VTSLM version 2.0 is not supported")


def test_truncated_in_the_header(good, tmp_path):
    path, _ = good
    p = tmp_path / "cut.vtslm"
    p.write_bytes(path.read_bytes()[:40])
    one_line_error(p, "truncated in the header")


def test_header_not_json(good, tmp_path):
    path, _ = good
    raw = bytearray(path.read_bytes())
    raw[16] = ord("#")
    p = tmp_path / "badjson.vtslm"
    p.write_bytes(bytes(raw))
    one_line_error(p, "the header is not valid JSON")


@pytest.mark.parametrize("key", sorted(vtslm.REQUIRED))
def test_each_required_header_key_missing(good, tmp_path, key):
    path, _ = good
    p = with_header(path, tmp_path / f"no-{key}.vtslm", lambda h: h.pop(key))
    one_line_error(p, f"header key '{key}' is missing")


@pytest.mark.parametrize(
    "key, value, what",
    [
        ("gate_rate_hz", "fast", "must be a positive number"),
        ("gate_rate_hz", -2000, "must be a positive number"),
        ("heads", 0, "must be a whole number from 1 to 255"),
        ("start_time", None, "must be a number"),
        ("dead_time_recorded", "yes", "must be true or false"),
        ("gate_t0_ns", 0.5, "must be a whole number"),
    ],
)
def test_bad_header_values(good, tmp_path, key, value, what):
    path, _ = good
    p = with_header(path, tmp_path / f"bad-{key}.vtslm", lambda h: h.__setitem__(key, value))
    msg = one_line_error(p, f"header key '{key}' {what}")
    assert repr(value) in msg


def test_truncated_in_the_records(good, tmp_path):
    path, _ = good
    raw = path.read_bytes()
    p = tmp_path / "cut.vtslm"
    p.write_bytes(raw[: len(raw) // 2])
    one_line_error(p, "truncated: block")


def test_truncated_in_a_block_header(good, tmp_path):
    path, _ = good
    raw = path.read_bytes()
    end = raw.rfind(b"END ")
    p = tmp_path / "cut.vtslm"
    p.write_bytes(raw[: end + 6])
    one_line_error(p, "truncated: a block header")


def test_no_end_block_is_an_unclosed_file(good, tmp_path):
    path, _ = good
    raw = path.read_bytes()
    p = tmp_path / "open.vtslm"
    p.write_bytes(raw[: raw.rfind(b"END ")])  # cut at a block boundary
    one_line_error(p, "no END block")


def test_a_writer_interrupted_by_an_error_leaves_a_file_the_reader_refuses(tmp_path):
    p = tmp_path / "crash.vtslm"
    with pytest.raises(RuntimeError):
        with VtslmWriter(p, start_time=1.0, duration_s=5.0, gate_rate_hz=100) as w:
            w.events([0.1], [1.0], [0.0], [0])
            raise RuntimeError("acquisition died")
    one_line_error(p, "no END block")


def test_bytes_after_the_end(good, tmp_path):
    path, _ = good
    p = tmp_path / "tail.vtslm"
    p.write_bytes(path.read_bytes() + b"garbage")
    one_line_error(p, "7 bytes after the END block")


def test_a_known_block_with_the_wrong_record_size(good, tmp_path):
    path, _ = good
    raw = bytearray(path.read_bytes())
    i = raw.find(b"TMRK")
    struct.pack_into("<I", raw, i + 8, 4)
    p = tmp_path / "size.vtslm"
    p.write_bytes(bytes(raw))
    one_line_error(p, "block 'TMRK'")


def test_a_garbled_block_tag(good, tmp_path):
    path, _ = good
    raw = bytearray(path.read_bytes())
    i = raw.find(b"TMRK")
    raw[i : i + 4] = b"\x00\xff\x01\x02"
    p = tmp_path / "tag.vtslm"
    p.write_bytes(bytes(raw))
    one_line_error(p, "bad block tag")


def test_event_times_going_backwards(tmp_path):
    p = tmp_path / "back.vtslm"
    with VtslmWriter(p, start_time=1.0, duration_s=5.0, gate_rate_hz=100) as w:
        w.events([0.1, 0.3], [1, 1], [0, 0], [0, 0])
        w.events([0.2], [1], [0], [0])
    one_line_error(p, "event times go backwards at record 2")


def test_an_event_on_a_head_the_header_does_not_have(tmp_path):
    p = tmp_path / "head.vtslm"
    with VtslmWriter(p, start_time=1.0, duration_s=5.0, gate_rate_hz=100, heads=2) as w:
        w.events([0.1], [1], [0], [3])
    one_line_error(p, "an event on head 3")


def test_the_writer_refuses_a_bad_header_before_writing(tmp_path):
    with pytest.raises(ValueError, match="gate_rate_hz"):
        VtslmWriter(tmp_path / "x.vtslm", start_time=1.0, duration_s=1.0, gate_rate_hz=0)
    assert not (tmp_path / "x.vtslm").exists()


@pytest.mark.parametrize(
    "header, words",
    [
        (b"[" * 5000 + b"]" * 5000, "the header is not valid JSON (nested too deeply)"),
        (b'{"heads": ' + b"9" * 5000 + b"}", "the header is not valid JSON (Exceeds the limit (4300 digits)"),
    ],
)
def test_a_header_json_refuses_beyond_syntax(tmp_path, header, words):
    p = tmp_path / "deep.vtslm"
    p.write_bytes(vtslm.PREAMBLE.pack(vtslm.MAGIC, 1, 0, len(header)) + header)
    one_line_error(p, words)


@pytest.mark.parametrize("key", ["start_time", "duration_s", "gate_t0_ns"])
def test_a_header_number_no_float_can_hold(good, tmp_path, key):
    """A 401-digit JSON integer: json gives an int that float() overflows on."""
    path, _ = good
    raw = path.read_bytes()
    _, _, _, length = vtslm.PREAMBLE.unpack_from(raw)
    header = json.loads(raw[16 : 16 + length])
    header[key] = 10**400
    text = json.dumps(header).encode()
    text += b" " * (-(16 + len(text)) % 8)
    p = tmp_path / "huge.vtslm"
    p.write_bytes(vtslm.PREAMBLE.pack(vtslm.MAGIC, 1, 0, len(text)) + text + raw[16 + length :])
    one_line_error(p, f"header key '{key}' must be a")


def test_failure_records_with_times_no_date_can_hold_are_left_out(tmp_path):
    # found by bench/fuzz.py (listmode_failures): OverflowError from float() and from the date of describe()
    from vts_hw.spect.listmode.failures import read_failure_records, write_failure_record

    write_failure_record(
        tmp_path, "good.vtslm", "the disk was full", by="the SPECT", start=1_795_000_000.0, end=1_795_000_060.0
    )
    head = '{"format": "vts-listmode-failure/1", "by": "x", "listmode": "a.vtslm", "reason": "r", '
    (tmp_path / "huge.failed.json").write_text(head + '"failed_at": 1' + "0" * 400 + "}")
    (tmp_path / "far.failed.json").write_text(head + '"start": 1e300, "failed_at": 1795000000}')
    (tmp_path / "nan.failed.json").write_text(head + '"failed_at": NaN}')
    records = read_failure_records(tmp_path)
    assert [r.listmode for r in records] == ["good.vtslm"]
    assert records[0].describe().startswith("the SPECT failed to record the scan (2026-")
