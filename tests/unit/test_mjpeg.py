"""MJPEG framing on the real multipart capture, with the faults a field stream has."""

import random
import re

from hypothesis import given, settings
from hypothesis import strategies as st

from vts_hw.recording.axis_jpeg import inspect_jpeg
from vts_hw.recording.mjpeg import MultipartParser, boundary_from_content_type, jpeg_end, read_frames_file, split_jpegs


def _real(axis_frames):
    data = (axis_frames / "t.mjpg").read_bytes()
    frames = [b for b, _ in read_frames_file(axis_frames / "t.mjpg")]
    return data, frames


def test_real_capture_has_16_whole_timestamped_frames(axis_frames):
    data, frames = _real(axis_frames)
    assert len(frames) == 16
    times = [inspect_jpeg(f).timestamp for f in frames]
    assert all(t is not None for t in times)
    assert all(0.05 <= b - a <= 0.07 for a, b in zip(times, times[1:]))
    # each body is exactly its Content-Length
    lengths = [int(x) for x in re.findall(rb"Content-Length: (\d+)", data)]
    assert [len(f) for f in frames] == lengths


def test_boundary_forms():
    assert boundary_from_content_type("multipart/x-mixed-replace; boundary=myboundary") == b"myboundary"
    assert boundary_from_content_type('multipart/x-mixed-replace;boundary="--myboundary"') == b"myboundary"


def _parse(data, boundary=b"myboundary", chunk=None):
    p = MultipartParser(boundary)
    out = []
    if chunk is None:
        out += p.feed(data)
    else:
        rng = random.Random(chunk)
        i = 0
        while i < len(data):
            k = rng.randint(1, 700)
            out += p.feed(data[i : i + k])
            i += k
    last = p.flush()
    if last is not None and last.body:
        out.append(last)
    return out


def test_chunked_feeding_gives_the_same_frames(axis_frames):
    data, frames = _real(axis_frames)
    for seed in range(5):
        parts = _parse(data, chunk=seed)
        assert [x.body for x in parts] == frames


def test_frame_is_handed_over_without_waiting_for_the_next(axis_frames):
    data, frames = _real(axis_frames)
    first_end = data.index(frames[0]) + len(frames[0])
    p = MultipartParser("myboundary")
    assert [x.body for x in p.feed(data[:first_end])] == [frames[0]]


def test_missing_content_length_and_odd_headers(axis_frames):
    data, frames = _real(axis_frames)
    mangled = re.sub(rb"Content-Length: \d+\r\n", b"", data).replace(b"Content-Type", b"content-TYPE")
    parts = _parse(mangled, boundary=b"--myboundary", chunk=3)
    assert [x.body for x in parts] == frames
    assert "no Content-Length" in parts[0].problems[0]


def test_wrong_content_length_falls_back_to_boundary(axis_frames):
    data, frames = _real(axis_frames)
    n = len(frames[3])
    mangled = data.replace(b"Content-Length: %d\r\n" % n, b"Content-Length: %d\r\n" % (n + 500), 1)
    parts = _parse(mangled)
    assert [x.body for x in parts] == frames
    assert any("does not match" in q for x in parts for q in x.problems)
    short = data.replace(b"Content-Length: %d\r\n" % n, b"Content-Length: %d\r\n" % (n - 700), 1)
    assert [x.body for x in _parse(short)] == frames


def test_torn_part_at_end_of_stream(axis_frames):
    data, frames = _real(axis_frames)
    cut = data[: data.index(frames[5]) + 1000]
    parts = _parse(cut)
    assert [x.body for x in parts[:5]] == frames[:5]
    assert not parts[5].complete


def test_split_concatenated_jpegs_with_a_torn_one(axis_frames):
    _, frames = _real(axis_frames)
    blob = frames[0] + frames[1][:1500] + frames[2] + frames[3]
    spans = split_jpegs(blob)
    assert [s.complete for s in spans] == [True, False, True, True]
    assert blob[spans[2].offset : spans[2].offset + spans[2].length] == frames[2]


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=2000))
def test_random_bytes_never_crash_the_parsers(data):
    parts = _parse(data)
    assert all(isinstance(x.body, bytes) for x in parts)
    spans = split_jpegs(data)
    assert all(0 <= s.offset < len(data) for s in spans)
    jpeg_end(data, 0)


@settings(max_examples=100, deadline=None)
@given(st.data())
def test_mangled_capture_keeps_every_untouched_frame(axis_frames, data):
    raw, frames = _real(axis_frames)
    b = bytearray(raw)
    # damage the bytes of one frame's JPEG body only: every other frame must come out intact
    k = data.draw(st.integers(0, 15))
    start = raw.index(frames[k])
    for _ in range(data.draw(st.integers(1, 5))):
        i = data.draw(st.integers(start + 200, start + len(frames[k]) - 3))
        b[i] = data.draw(st.integers(0, 255))
    bodies = [x.body for x in _parse(bytes(b), chunk=data.draw(st.integers(0, 99)))]
    for j, f in enumerate(frames):
        if j != k:
            assert f in bodies
