"""The Axis comment segments, read from real frames of three firmware versions."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vts_hw.recording.axis_jpeg import AxisProduct, AxisTime, JpegError, axis_timestamp, inspect_jpeg, stamp_jpeg


def test_firmware_6_frame(axis_frames):
    info = inspect_jpeg((axis_frames / "tst.jpg").read_bytes())
    assert info.complete and info.problems == ()
    assert info.time.seconds == 0x59955EE8 and info.time.hundredths == 0x2C
    assert info.timestamp == pytest.approx(1502961384.44)
    assert info.product.firmware_str == "6.15.70"
    assert info.product.mac_str == "AC:CC:8E:02:B4:36"
    assert (info.width, info.height) == (352, 240)


def test_firmware_4_torn_frame_product_first(axis_frames):
    # product segment before the time segment, extra time bytes zero, and cut short
    info = inspect_jpeg((axis_frames / "img00012680.jpg").read_bytes())
    assert info.time.extra == b"\x00" * 5
    assert info.timestamp == pytest.approx(1273508725.72)
    assert info.product.firmware == (4, 47, 13)
    assert info.product.mac_str.startswith("00:40:8C")
    assert not info.complete
    assert any("cut short" in p for p in info.problems)


def test_plain_jpeg_is_answered_not_failed(axis_frames):
    info = inspect_jpeg((axis_frames / "00000000.jpg").read_bytes())
    assert info.time is None and info.product is None and info.complete
    assert "no Axis time segment" in info.problems
    assert axis_timestamp((axis_frames / "00000000.jpg").read_bytes()) is None


def test_not_a_jpeg_raises_clearly():
    with pytest.raises(JpegError, match="start-of-image"):
        inspect_jpeg(b"GIF89a....")


def _jpeg(w=64, h=48, q=75):
    ok, buf = cv2.imencode(".jpg", np.full((h, w), 40, np.uint8), [cv2.IMWRITE_JPEG_QUALITY, q])
    return buf.tobytes()


PRODUCT = AxisProduct(0x01A2, (5, 55, 1), bytes.fromhex("ACCC8E19256D"))


def test_stamp_matches_real_layout(axis_frames):
    stamped = stamp_jpeg(_jpeg(), 1445859308.91, PRODUCT)
    real = (axis_frames / "t.mjpg").read_bytes()
    real_jpeg = real[real.index(b"\xff\xd8") :]
    # the 34 bytes of the two segments, as a firmware 5.55 camera wrote them for that second
    assert stamped[20:54] == real_jpeg[20:54]
    decoded = cv2.imdecode(np.frombuffer(stamped, np.uint8), cv2.IMREAD_UNCHANGED)
    assert decoded.shape == (48, 64)


@given(st.floats(min_value=0, max_value=2**32 - 1, allow_nan=False))
def test_time_round_trip_at_10ms(epoch):
    t = AxisTime.from_epoch(epoch)
    assert 0 <= t.hundredths <= 99
    back = inspect_jpeg(stamp_jpeg(_jpeg(8, 8), epoch, PRODUCT)).timestamp
    assert back == t.epoch
    assert epoch - 0.01 - 1e-6 * max(1, epoch) <= back <= epoch + 1e-6 * max(1, epoch)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600))
def test_random_bytes_never_crash(data):
    try:
        info = inspect_jpeg(data)
    except JpegError:
        assert not data.startswith(b"\xff\xd8")
        return
    assert data.startswith(b"\xff\xd8")
    assert isinstance(info.problems, tuple)


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_mangled_real_frames_never_crash(axis_frames, data):
    src = (axis_frames / "tst.jpg").read_bytes()
    b = bytearray(src)
    for _ in range(data.draw(st.integers(0, 8))):
        i = data.draw(st.integers(0, len(b) - 1))
        b[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(2, len(b)))
    try:
        info = inspect_jpeg(bytes(b[:cut]))
    except JpegError:
        return
    if cut < len(src) - 2:
        assert not info.complete or bytes(b[:cut]).rstrip(b"\r\n\x00").endswith(b"\xff\xd9")
