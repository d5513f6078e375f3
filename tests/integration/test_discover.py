"""`vts discover` finds the simulated cameras as they announce themselves on loopback (mDNS
``_axis-video._tcp`` through zeroconf, SSDP ``M-SEARCH``), confirms each over VAPIX and writes a
rig.yaml that `vts` then loads; the messages of both protocols byte for byte.

The searches run with ``--interface 127.0.0.1``: multicast stays on ``lo`` (it works there on
Linux; docs/decisions/0067-discover-and-setup.md). Another run of these tests on the same machine
announces other cameras on the same loopback: the checks ask that ours are found, with their
serials, not that nothing else is.
"""

from __future__ import annotations

import os
import shutil
import socket
import struct
import subprocess
import sys

import pytest
import yaml

from inprocess_cli import vts
from scripted_http import ScriptedHTTP
from vts_hw.config import load_rig
from vts_hw.drivers.discovery import Announcement, merge, search
from vts_hw.drivers.discovery.ssdp import describe, location, m_search
from vts_hw.sim_devices.announce import SSDP_GROUP
from vts_hw.sim_devices.rig import SimRig

LO = "127.0.0.1"
MODELS = ["p1375", "axis211", "p1375", "axis211"]


@pytest.fixture(scope="module")
def rig4():
    with SimRig(n_cameras=4, seed=24, firmware=MODELS, announce=True) as rig:
        yield rig


def _ours(rig, rows):
    serials = {srv.serial: name for name, srv in rig.servers.items()}
    return {serials[r["serial"]]: r for r in rows if r["serial"] in serials}


def test_discover_finds_the_four_cameras_and_writes_a_rig_that_vts_loads(rig4, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("VTS_CAMERA_PASSWORD", rig4.password)
    out = tmp_path / "rig.yaml"
    code, stdout, err = vts(capsys, "discover", "--interface", LO, "--timeout", "3", "-o", out)
    assert code == 0, err
    for srv in rig4.servers.values():  # the table: every camera, its serial, model and firmware
        line = next(x for x in stdout.splitlines() if srv.serial in x)
        assert f"{LO}:{srv.port}" in line and "confirmed" in line and "NOT" not in line, line
        assert (
            ("AXIS 211" in line and "4.47" in line)
            if srv.model == "axis211"
            else ("AXIS P1375" in line and "10.12.240" in line)
        ), line
        assert "mdns+ssdp" in line, line
    rig = load_rig(out)  # the skeleton loads as a rig config ...
    by_serial = {c.port: c for c in rig.cameras}
    for srv in rig4.servers.values():
        cfg = by_serial[srv.port]
        assert (cfg.host, cfg.password_env, cfg.user) == (LO, "VTS_CAMERA_PASSWORD", "root")
    text = out.read_text()
    assert all(srv.serial in text for srv in rig4.servers.values())  # each entry says what it is
    first_211 = next(srv for srv in rig4.servers.values() if srv.model == "axis211")
    name = next(c.name for c in rig.cameras if c.port == first_211.port)
    code, stdout, err = vts(capsys, "camera", "info", name, "--config", out, "--json")  # ... and vts talks to it
    assert code == 0, err
    assert yaml.safe_load(stdout)["device"]["SerialNumber"] == first_211.serial


def test_discover_json_and_what_each_protocol_heard(rig4, capsys, monkeypatch):
    monkeypatch.setenv("VTS_CAMERA_PASSWORD", rig4.password)
    code, stdout, err = vts(capsys, "discover", "--interface", LO, "--timeout", "2", "--json")
    assert code == 0, err
    ours = _ours(rig4, yaml.safe_load(stdout)["cameras"])
    assert set(ours) == set(rig4.servers)
    for name, row in ours.items():
        srv = rig4.servers[name]
        assert (row["host"], row["port"], row["confirmed"]) == (LO, srv.port, True)
        assert sorted(row["announced_by"]) == ["mdns", "ssdp"]
        assert row["firmware"] == srv.params.get("Properties.Firmware.Version")


def test_each_protocol_alone_finds_them(rig4):
    mdns_only = search(2.0, [LO], ssdp=False)
    ssdp_only = search(2.0, [LO], mdns=False)
    for found in (mdns_only, ssdp_only):
        got = {f.serial: f for f in found}
        for srv in rig4.servers.values():
            assert got[srv.serial].port == srv.port
            assert got[srv.serial].model == srv.params.get("Brand.ProdShortName")
    assert {f.sources for f in mdns_only} == {("mdns",)} and {f.sources for f in ssdp_only} == {("ssdp",)}


def test_discover_never_overwrites_a_file_and_searches_nothing_then(tmp_path, capsys):
    out = tmp_path / "rig.yaml"
    out.write_text("# mine\n")
    code, stdout, err = vts(capsys, "discover", "--interface", LO, "--timeout", "30", "-o", out)
    assert code == 2 and f"{out} already exists" in err and "never overwritten" in err, err
    assert "listening" not in err and out.read_text() == "# mine\n"


def test_without_the_password_the_cameras_are_listed_but_not_confirmed(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("VTS_NO_SUCH_PASSWORD", raising=False)
    with SimRig(n_cameras=1, seed=31, announce=True) as rig:
        srv = rig.servers["cam1"]
        out = tmp_path / "rig.yaml"
        code, stdout, err = vts(
            capsys, "discover", "--interface", LO, "--timeout", "2", "-o", out, "--password-env", "VTS_NO_SUCH_PASSWORD"
        )
    assert code == 4, err
    line = next(x for x in stdout.splitlines() if srv.serial in x)
    assert "NOT confirmed" in line and "?" in line  # the firmware is not known
    assert "set VTS_NO_SUCH_PASSWORD" in err and "Traceback" not in err
    text = out.read_text()  # written all the same, saying so
    assert "NOT confirmed over VAPIX" in text and load_rig(out).cameras


def test_no_camera_found_writes_nothing(tmp_path):
    """In a network namespace of its own (``unshare -n``; CI runs as root), where no test run's
    cameras can be announcing: nothing found is exit 4, and the rig.yaml is not written."""
    if os.geteuid() != 0 or not shutil.which("unshare") or not shutil.which("ip"):
        pytest.skip("a network namespace of its own needs root, unshare and ip (CI has them)")
    out = tmp_path / "rig.yaml"
    r = subprocess.run(
        [
            "unshare",
            "-n",
            "sh",
            "-c",
            f'ip link set lo up && exec "{sys.executable}" -m vts_hw.cli.__main__ discover '
            f'--interface {LO} --timeout 1 -o "{out}"',
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 4 and "no Axis camera announced itself within 1 s on 127.0.0.1" in r.stderr, r.stderr
    assert not out.exists() and f"{out} was not written" in r.stderr and "Traceback" not in r.stderr


def test_bad_interface_and_timeout_are_bad_input(capsys):
    for args in (["--interface", "eth0"], ["--timeout", "0"], ["--timeout", "nan"], ["--password-env", "1x"]):
        code, out, err = vts(capsys, "discover", *args)
        assert code == 2 and "Traceback" not in err, (args, err)


# -- the protocols byte for byte ------------------------------------------------------------
def test_m_search_is_the_ssdp_request_byte_for_byte():
    assert m_search(2) == (
        b'M-SEARCH * HTTP/1.1\r\nHOST: 239.255.255.250:1900\r\nMAN: "ssdp:discover"\r\nMX: 2\r\nST: ssdp:all\r\n\r\n'
    )


def test_the_simulated_cameras_answer_an_m_search_as_axis_cameras_do(rig4):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((LO, 0))
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(LO))
    s.settimeout(2)
    try:
        s.sendto(m_search(1).replace(b"ssdp:all", b"urn:axis-com:service:BasicService:1"), (SSDP_GROUP, 1900))
        answers = {}
        while len(answers) < 4:
            data, addr = s.recvfrom(8192)
            answers[data] = addr
    finally:
        s.close()
    want = {srv.port: srv.serial for srv in rig4.servers.values()}
    got = {}
    for data in answers:
        lines = data.decode().split("\r\n")
        assert lines[0] == "HTTP/1.1 200 OK" and data.endswith(b"\r\n\r\n"), data
        headers = dict(line.split(": ", 1) if ": " in line else (line.rstrip(":"), "") for line in lines[1:-2])
        assert headers["ST"] == "urn:axis-com:service:BasicService:1" and headers["EXT"] == ""
        port = int(headers["LOCATION"].split(":")[2].split("/")[0])
        assert headers["LOCATION"] == f"http://{LO}:{port}/rootdesc1.xml"
        assert headers["USN"] == f"uuid:Upnp-BasicDevice-1_0-{want[port]}::urn:axis-com:service:BasicService:1"
        got[port] = location(data)
    assert set(want) <= set(got)
    a = describe(got[next(iter(want))])
    assert a == Announcement("ssdp", LO, a.port, want[a.port], a.model) and a.model.startswith("AXIS")


@pytest.mark.parametrize(
    "datagram",
    [
        b"",
        b"\xff\xfe",
        b"HTTP/1.1 200\r\n\r\n",
        b"NOTIFY * HTTP/1.1\r\n\r\n",
        b"HTTP/1.1 404 Not Found\r\nLOCATION: http://x/\r\n\r\n",
        b"HTTP/1.1 200 OK\r\nLOCATION: file:///etc/passwd\r\n\r\n",
    ],
)
def test_what_is_not_an_ssdp_answer_with_a_location_is_left_out(datagram):
    assert location(datagram) is None


def test_a_description_that_is_not_an_axis_camera_is_left_out():
    bodies = {
        "/tv.xml": '<root xmlns="urn:schemas-upnp-org:device-1-0"><device><manufacturer>Samsung</manufacturer>'
        "<serialNumber>1</serialNumber></device></root>",
        "/bad.xml": "<root><device",
        "/bomb.xml": "<a>" + "x" * (300 * 1024) + "</a>",
    }
    with ScriptedHTTP([(f"GET {path}", None, body) for path, body in bodies.items()]) as peer:
        for path in bodies:
            assert describe(peer.url + path) is None, path
    peer.assert_complete()
    assert describe(f"http://{LO}:1/nothing-listens.xml", timeout=1) is None


def test_merge_takes_one_camera_per_serial_and_notes_a_second_address():
    found = merge(
        [
            Announcement("mdns", "10.0.0.5", 80, "accc8e000001", "AXIS P1375"),
            Announcement("ssdp", "10.0.0.5", 80, "ACCC8E000001", ""),
            Announcement("ssdp", "10.0.1.5", 80, "ACCC8E000001", "AXIS P1375"),
            Announcement("ssdp", "10.0.0.4", 8080, "00408C000002", "AXIS 211"),
        ]
    )
    assert [(f.host, f.serial, f.sources) for f in found] == [
        ("10.0.0.4", "00408C000002", ("ssdp",)),
        ("10.0.0.5", "ACCC8E000001", ("mdns", "ssdp")),
    ]
    assert found[1].notes == ["ssdp also announced it at 10.0.1.5:80"]


def test_the_responder_hears_loopback_multicast_only(rig4):
    """Its socket is bound to the group address (never reachable by unicast) and joined on lo."""
    sock = rig4.announcer._sock
    assert sock.getsockname() == (SSDP_GROUP, 1900)
    mreq_if = sock.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, 4)
    assert socket.inet_ntoa(struct.pack("4s", mreq_if)) == LO
