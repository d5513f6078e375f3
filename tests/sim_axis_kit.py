"""The simulated Axis camera's test kit: a fake frame source with the SimCameraSource interface,
cameras serving it over HTTP on loopback (fixtures ``source``, ``cam``, ``cam2``), and clients
written here, independent of the server code: a raw socket client with its own digest
computation, the multipart stream walked byte by byte."""

from __future__ import annotations

import hashlib
import re
import secrets
import socket
import time

import cv2
import numpy as np
import pytest
import requests
from requests.auth import HTTPDigestAuth

from vts_hw.recording.axis_jpeg import AxisProduct, stamp_jpeg
from vts_hw.sim_devices.axis_camera import SimAxisCamera

PASSWORD = "s3cret pw"
AUTH = HTTPDigestAuth("root", PASSWORD)
PART_RE = re.compile(rb"--myboundary\r\nContent-Type: image/jpeg\r\nContent-Length: (\d+)\r\n\r\n")


# ----------------------------------------------------------------------------------------
# A fake frame source with the SimCameraSource interface
# ----------------------------------------------------------------------------------------
class FakeSource:
    """640x480 frames: a textured background, four disks that are bright only with the LED on."""

    def __init__(self, name: str = "cam0", offset_s: float = 3.25, render_s: float = 0.0):
        self.name, self.width, self.height = name, 640, 480
        self.render_s = render_s  # time a frame takes to make (after its stamp)
        self.product = AxisProduct(0x01A2, (5, 55, 1), bytes.fromhex("ACCC8E192567"))
        self.offset_s = offset_s
        self.led_calls: list[tuple] = []
        self._led, self._pulse_until = False, 0.0
        rng = np.random.default_rng(1)
        self._background = (rng.normal(30, 8, (480, 640)).clip(0, 255)).astype(np.uint8)
        self._disks = np.zeros((480, 640), np.uint8)
        for x, y in ((160, 120), (480, 120), (160, 360), (480, 360)):
            cv2.circle(self._disks, (x, y), 12, 255, -1)

    def camera_time(self, host_t: float | None = None) -> float:
        return (time.time() if host_t is None else host_t) + self.offset_s

    def set_led(self, on: bool) -> None:
        self.led_calls.append(("set", on))
        self._led, self._pulse_until = bool(on), 0.0

    def pulse_led(self, duration_s: float) -> None:
        self.led_calls.append(("pulse", duration_s))
        self._pulse_until = time.time() + duration_s

    def led_on(self) -> bool:
        return self._led or time.time() < self._pulse_until

    def jpeg(self, quality: int, host_t: float | None = None) -> tuple[bytes, float]:
        epoch = self.camera_time(host_t)
        image = np.maximum(self._background, self._disks) if self.led_on() else self._background
        ok, enc = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
        time.sleep(self.render_s)
        return stamp_jpeg(enc.tobytes(), epoch, self.product), epoch


@pytest.fixture
def source():
    return FakeSource()


@pytest.fixture
def cam(source):
    with SimAxisCamera(source, password=PASSWORD) as camera:
        yield camera


@pytest.fixture
def cam2(source):
    with SimAxisCamera(source, password=PASSWORD, firmware="vapix2") as camera:
        yield camera


# ----------------------------------------------------------------------------------------
# A raw client with its own digest computation, for byte-exact checks
# ----------------------------------------------------------------------------------------
def _md5(text: str) -> str:
    return hashlib.md5(text.encode()).hexdigest()


def auth_header(cam, path: str, method: str = "GET", password: str = PASSWORD) -> str:
    """Ask for a challenge, answer it the RFC 7616 way (MD5, qop=auth)."""
    challenge = requests.request(method, cam.url + path).headers["WWW-Authenticate"]
    fields = dict(re.findall(r'(\w+)="?([^",]*)"?', challenge))
    cnonce, nc = secrets.token_hex(8), "00000001"
    ha1 = _md5(f"root:{fields['realm']}:{password}")
    ha2 = _md5(f"{method}:{path}")
    response = _md5(f"{ha1}:{fields['nonce']}:{nc}:{cnonce}:auth:{ha2}")
    return (
        f'Digest username="root", realm="{fields["realm"]}", nonce="{fields["nonce"]}", uri="{path}", '
        f'response="{response}", qop=auth, nc={nc}, cnonce="{cnonce}", opaque="{fields["opaque"]}"'
    )


class Raw:
    """One connection: ``with Raw(...) as (sock, reader)`` closes both ends on exit (a
    socket with a reader made by makefile() stays open until the reader is closed too)."""

    def __init__(self, sock: socket.socket):
        self.sock, self.reader = sock, sock.makefile("rb")

    def __iter__(self):
        return iter((self, self.reader))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self.reader.close()
        self.sock.close()


def raw_request(cam, path: str, auth: bool = True, timeout: float = 5.0) -> Raw:
    """Send one GET on a fresh socket; unpacks as (connection, binary reader)."""
    sock = socket.create_connection(("127.0.0.1", cam.port), timeout=timeout)
    head = f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n"
    if auth:
        head += f"Authorization: {auth_header(cam, path)}\r\n"
    sock.sendall((head + "\r\n").encode())
    return Raw(sock)


def read_head(reader) -> tuple[bytes, dict[str, str]]:
    status = reader.readline()
    headers = {}
    while (line := reader.readline()) not in (b"\r\n", b""):
        key, _, value = line.decode("latin-1").partition(":")
        headers[key.strip().lower()] = value.strip()
    return status, headers


def read_all(reader, limit_s: float = 8.0) -> bytes:
    data, t_end = bytearray(), time.monotonic() + limit_s
    while time.monotonic() < t_end:
        chunk = reader.read1(65536)
        if not chunk:
            return bytes(data)
        data += chunk
    raise AssertionError("the stream did not end")


def walk_parts(body: bytes) -> list[tuple[int, bytes]]:
    """Walk a multipart body strictly by Content-Length; fails on any deviation from the
    layout of the real capture: boundary line, two headers, blank line, JPEG, CRLF."""
    parts, pos = [], 0
    while pos < len(body):
        m = PART_RE.match(body, pos)
        assert m, f"no part header at byte {pos}: {body[pos : pos + 80]!r}"
        n = int(m.group(1))
        jpeg = body[m.end() : m.end() + n]
        assert body[m.end() + n : m.end() + n + 2] == b"\r\n", "a part must end with CRLF"
        parts.append((n, jpeg))
        pos = m.end() + n + 2
    return parts


def stream(cam, query: str = "", limit_s: float = 8.0) -> tuple[bytes, dict, bytes]:
    sock, reader = raw_request(cam, "/axis-cgi/mjpg/video.cgi" + query)
    with sock:
        status, headers = read_head(reader)
        return status, headers, read_all(reader, limit_s)


def get(cam, path: str, **kw) -> requests.Response:
    return requests.get(cam.url + path, auth=AUTH, timeout=5, **kw)
