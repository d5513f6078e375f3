"""Recording folders written from real Axis frames: byte-exact, indexed, rebuildable."""

import json

import pytest

from vts_hw.errors import DataError
from vts_hw.recording.axis_jpeg import inspect_jpeg
from vts_hw.recording.folder import load_manifest, read_index
from vts_hw.recording.mjpeg import read_frames_file
from vts_hw.recording.promised import info
from vts_hw.recording.reindex import reindex
from vts_hw.recording.writer import Recording


@pytest.fixture()
def real_frames(axis_frames):
    return [b for b, _ in read_frames_file(axis_frames / "t.mjpg")]


def _record(folder, frames, skip=()):
    with Recording(folder, ["cam1"], {"rig": "test"}) as rec:
        for i, f in enumerate(frames):
            if i in skip:
                continue
            rec.write_frame("cam1", f, inspect_jpeg(f).timestamp, 1000.0 + i * 0.06)
    return rec


def test_byte_exact_mjpeg_and_index(tmp_path, real_frames):
    _record(tmp_path, real_frames)
    data = (tmp_path / "cam1.mjpeg").read_bytes()
    assert data == b"".join(real_frames)
    rows = read_index(tmp_path / "cam1.index.csv")
    assert len(rows) == 16
    for r, f in zip(rows, real_frames):
        assert data[r.offset : r.offset + r.length] == f
        assert r.camera_time == pytest.approx(inspect_jpeg(f).timestamp)
    m = json.loads((tmp_path / "manifest.json").read_text())
    assert m["status"] == "complete" and m["cameras"]["cam1"]["frames"] == 16


def test_reindex_from_mjpeg_alone_keeps_host_times(tmp_path, real_frames):
    _record(tmp_path, real_frames)
    before = (tmp_path / "cam1.index.csv").read_text()
    (tmp_path / "cam1.index.csv").write_text(
        before.splitlines()[0] + "\n" + "\n".join(before.splitlines()[1:6]) + "\n3,99"
    )
    report = reindex(tmp_path)
    c = report["cam1"]
    assert (c.frames, c.host_times_kept, c.torn, c.replaced) == (16, 5, 0, True)
    after = read_index(tmp_path / "cam1.index.csv")
    assert [r.offset for r in after] == [r.offset for r in read_index_from_text(tmp_path, before)]
    (tmp_path / "cam1.index.csv").unlink()
    assert reindex(tmp_path)["cam1"].frames == 16


def read_index_from_text(tmp_path, text):
    p = tmp_path / "copy.csv"
    p.write_text(text)
    return read_index(p)


def test_frame_in_flight_at_a_kill_is_left_out_and_reported(tmp_path, real_frames):
    _record(tmp_path, real_frames)
    with open(tmp_path / "cam1.mjpeg", "ab") as f:
        f.write(real_frames[0][:1234])  # the frame being written when the process died
    summary = info(tmp_path)[0]
    assert summary.frames == 16 and any("reindex" in p for p in summary.problems)
    report = reindex(tmp_path)
    assert report["cam1"].frames == 16 and report["cam1"].torn == 1


def test_info_reports_gaps_from_camera_times(tmp_path, real_frames):
    _record(tmp_path, real_frames, skip={5, 6, 7})
    s = info(tmp_path)[0]
    assert s.frames == 13
    assert len(s.gaps) == 1 and s.gaps[0]["missing"] == 3 and s.gaps[0]["after_frame"] == 4
    assert s.fps == pytest.approx(16.667, abs=0.01)


def test_info_on_files_and_bad_paths(tmp_path, axis_frames):
    (s,) = info(axis_frames / "img00012680.jpg")
    assert s.torn == 1 and s.frames == 1
    (s,) = info(axis_frames / "00000000.jpg")
    assert s.with_time == 0 and any("no Axis time" in p for p in s.problems)
    with pytest.raises(DataError, match="no such file"):
        info(tmp_path / "nothing")
    (tmp_path / "junk.bin").write_bytes(b"hello")
    with pytest.raises(DataError, match="no JPEG frames"):
        info(tmp_path / "junk.bin")


# ---- bad index files (found by bench/fuzz.py): a DataError naming the file, never a traceback


def test_an_index_that_is_not_ascii_text(tmp_path, real_frames):
    _record(tmp_path, real_frames[:3])
    idx = tmp_path / "cam1.index.csv"
    idx.write_bytes(b"frame,offset,length,camera_time,host_time\n0,0,\xff\xd8,1.0,2.0\n")
    with pytest.raises(DataError, match=r"cam1.index.csv: not a recording index \(byte 46 is not ASCII text\)"):
        read_index(idx)
    with pytest.raises(DataError, match="not a recording index"):
        info(tmp_path)


@pytest.mark.parametrize("bad", ["1,nan-ish,5,,", "1,100,-5,,", "1,100,5,inf,", "1,100,5,,1e400", "1,100,5"])
def test_a_bad_line_before_the_last_is_an_error_not_the_end(tmp_path, real_frames, bad):
    _record(tmp_path, real_frames[:3])
    idx = tmp_path / "cam1.index.csv"
    lines = idx.read_text().splitlines()
    idx.write_text("\n".join(lines[:2] + [bad] + lines[2:]) + "\n")
    with pytest.raises(
        DataError, match=r"cam1.index.csv: line 3 is not a frame,offset,length,camera_time,host_time row"
    ):
        read_index(idx)
    idx.write_text("\n".join(lines + [bad]))  # the same line last: the frame in flight at a kill
    assert len(read_index(idx)) == 3


def test_info_of_camera_times_with_an_absurd_frame_step(tmp_path):
    # a median step of 1e-310 s: the gap in frames is not a finite number
    s = __import__("vts_hw.recording.folder", fromlist=["summarize_times"]).summarize_times(
        "cam1", [0.0, 1e-310, 2e-310, 5.0]
    )
    assert len(s.gaps) == 1 and s.gaps[0]["missing"] >= 1


@pytest.mark.parametrize(
    "text, words",
    [
        (b"[]", "not a recording manifest (expected a JSON object, got a list)"),
        (b'{"cameras": []}', 'not a recording manifest ("cameras" must map each camera name to its entry)'),
        (b'{"cameras": {"cam1": 3}}', 'not a recording manifest ("cameras" must map each camera name to its entry)'),
        (
            b'{"cameras": {"cam1": {"gaps": {"missing": 3}}}}',
            "not a recording manifest (cameras.cam1.gaps must be a list of gaps",
        ),
        (
            b'{"cameras": {"cam1": {"gaps": [{"missing": "3"}]}}}',
            "not a recording manifest (cameras.cam1.gaps must be a list of gaps",
        ),
        (b'{"cameras": {"cam1"', "not a recording manifest (not valid JSON)"),
        (b"\xff\xd8\xff\xe0", "not a recording manifest (not valid JSON)"),
        (b"[" * 100_000, "not a recording manifest (not valid JSON)"),
    ],
)
def test_load_manifest_of_the_wrong_shape(tmp_path, text, words):
    (tmp_path / "manifest.json").write_bytes(text)
    with pytest.raises(DataError) as ei:
        load_manifest(tmp_path)
    assert str(ei.value).startswith(f"{tmp_path / 'manifest.json'}: {words}")


def test_load_manifest_of_a_recording_and_of_no_manifest(tmp_path, real_frames):
    _record(tmp_path, real_frames[:2])
    assert load_manifest(tmp_path)["cameras"]["cam1"]["frames"] == 2
    (tmp_path / "manifest.json").unlink()
    assert load_manifest(tmp_path, missing_ok=True) is None
    with pytest.raises(DataError, match="not a recording folder"):
        load_manifest(tmp_path)


def test_a_lenient_read_keeps_every_whole_row_for_a_rebuild(tmp_path, real_frames):
    _record(tmp_path, real_frames[:4])
    idx = tmp_path / "cam1.index.csv"
    lines = idx.read_text().splitlines()
    idx.write_text("\n".join(lines[:2] + ["garbage", "7,12,-1,,"] + lines[2:]) + "\n")
    with pytest.raises(DataError, match="line 3 is not a frame"):
        read_index(idx)
    rows = read_index(idx, lenient=True)
    assert [r.frame for r in rows] == [0, 1, 2, 3] and all(r.host_time for r in rows)


def test_info_counts_what_is_readable_and_names_what_is_missing(tmp_path):
    """Issue 21 §3: `vts recording info` on a .mjpeg cut short counts the readable frames, not the
    index's rows; a camera of the manifest whose files are gone is listed, its files named; the
    exit status is 3 (not whole), 0 for a whole recording."""
    import json
    import subprocess
    import sys

    from lossy_recording import cut_mjpeg, remove_camera
    from vts_hw.sim_devices.recording_sim import simulate_recording

    rec = tmp_path / "rec"
    simulate_recording(rec, duration_s=2.0, seed=1, add_band=False)

    def info(*extra):
        return subprocess.run(
            [sys.executable, "-m", "vts_hw.cli", "recording", "info", str(rec), *extra],
            capture_output=True,
            text=True,
            timeout=120,
        )

    whole = info("--json")
    assert whole.returncode == 0, whole.stderr
    n = {s["source"]: s["frames"] for s in json.loads(whole.stdout)}
    assert set(n) == {"cam1", "cam2"} and all(v >= 45 for v in n.values())
    cut_mjpeg(rec, "cam1", 0.5)
    remove_camera(rec, "cam2")
    p = info("--json")
    by = {s["source"]: s for s in json.loads(p.stdout)}
    assert p.returncode == 3 and "Traceback" not in p.stderr
    assert by["cam1"]["promised"] == n["cam1"] and 0 < by["cam1"]["frames"] < n["cam1"] and not by["cam1"]["whole"]
    assert by["cam2"]["frames"] == 0 and by["cam2"]["promised"] == n["cam2"]
    assert by["cam2"]["missing_files"] == ["cam2.mjpeg", "cam2.index.csv"]
    line = p.stderr.strip()
    assert line.startswith("vts: ") and len(line.splitlines()) == 1 and "is not whole" in line
    assert f"cam1: {by['cam1']['frames']} of {n['cam1']} frames promised are readable" in line
    assert "cam2.mjpeg and cam2.index.csv missing" in line
    text = info().stdout
    assert f"cam1: {by['cam1']['frames']} of {n['cam1']} promised frame(s) readable" in text
    assert "cam2: 0 of" in text and "cam2.mjpeg and cam2.index.csv missing" in text


def test_ctrl_c_between_a_frames_two_writes_leaves_no_part_of_it(tmp_path, monkeypatch):
    """KeyboardInterrupt after a frame's bytes reached the .mjpeg but before its index line:
    both files are cut back to the last whole frame, as on a full disk (the index covers the
    .mjpeg exactly; found by the SIGINT sweep of bench/bad_inputs.py)."""
    import vts_hw.recording.writer as writer

    folder = tmp_path / "rec"
    with Recording(folder, ["cam1"], {"rig": "test"}) as rec:
        rec.write_frame("cam1", b"\xff\xd8one\xff\xd9", 100.0, 1.0)
        real, calls = writer._write_all, []

        def interrupted(fd, data):
            calls.append(fd)
            if len(calls) == 2:  # the index line, after the frame's bytes
                raise KeyboardInterrupt
            real(fd, data)

        monkeypatch.setattr(writer, "_write_all", interrupted)
        with pytest.raises(KeyboardInterrupt):
            rec.write_frame("cam1", b"\xff\xd8two\xff\xd9", 100.04, 1.04)
        monkeypatch.setattr(writer, "_write_all", real)
    rows = read_index(folder / "cam1.index.csv")
    assert len(rows) == 1 and (folder / "cam1.mjpeg").stat().st_size == rows[-1].offset + rows[-1].length
