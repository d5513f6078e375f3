"""The LED's state read back from an Axis camera (issue 23: the Room page shows the LED as the
camera says it, not as it was last switched).

* On the wire, byte for byte: what the driver sends (``GET /axis-cgi/io/port.cgi?checkactive=1``;
  on VAPIX 2 firmware, after port.cgi's 404, ``GET /axis-cgi/io/output.cgi?check=1``) and how it
  reads the firmware's replies (``port1=active``/``inactive``, ``output1=1``/``0``), against a
  server given those exact exchanges (tests/scripted_http.py); a reply of another shape is one sentence.
* The simulated camera of both profiles (AXIS P1375, current firmware; AXIS 211, firmware 4.47)
  answers those requests as the firmware does, byte for byte, and the driver reads its LED
  back through them; its ``led_held`` fault (an action rule holding the output) answers a
  switch OK and leaves the output as it was, which the state query tells.
* `vts camera led` reads every switch back (vts_hw/camera_led.py): a switch the camera's output
  does not show is exit 4 in one sentence, never "OK" (issue 32 §4).
"""

from __future__ import annotations

import pytest

from inprocess_cli import vts
from scripted_http import ScriptedHTTP
from sim_axis_kit import PASSWORD, raw_request, read_head
from vts_hw.config import dump_rig
from vts_hw.drivers.axis import AxisCamera, BadReply
from vts_hw.sim_devices.rig import SimRig

pytestmark = pytest.mark.timeout(60)


PORT_CGI, OUTPUT_CGI = "GET /axis-cgi/io/port.cgi?checkactive=1", "GET /axis-cgi/io/output.cgi?check=1"


@pytest.mark.parametrize("body, state", [("port1=active\r\n", True), ("port1=inactive\r\n", False)])
def test_the_driver_asks_port_cgi_checkactive_and_reads_the_reply(body, state):
    with ScriptedHTTP([(PORT_CGI, None, body)]) as wire, AxisCamera("cam1", wire.url, user=None) as cam:
        assert cam.led_state() is state
        assert wire.lines[0] == "GET /axis-cgi/io/port.cgi?checkactive=1 HTTP/1.1"
    wire.assert_complete()


def test_vapix2_firmware_is_asked_through_output_cgi_check():
    not_found = (404, "<HTML><BODY><H1>404 Not Found</H1></BODY></HTML>\r\n")
    script = [(PORT_CGI, None, not_found), (OUTPUT_CGI, None, "output1=0\r\n"), (OUTPUT_CGI, None, "output1=1\r\n")]
    with ScriptedHTTP(script) as wire, AxisCamera("cam1", wire.url, user=None, led_port=1) as cam:
        assert cam.led_state() is False
        assert cam.led_state() is True  # remembered: output.cgi straight away
        assert wire.lines == [
            "GET /axis-cgi/io/port.cgi?checkactive=1 HTTP/1.1",
            "GET /axis-cgi/io/output.cgi?check=1 HTTP/1.1",
            "GET /axis-cgi/io/output.cgi?check=1 HTTP/1.1",
        ]
    wire.assert_complete()


@pytest.mark.parametrize("body", ["port2=active\r\n", "port1=maybe\r\n", "", "OK\r\n"])
def test_a_reply_of_another_shape_is_one_sentence(body):
    with ScriptedHTTP([(PORT_CGI, None, body)]) as wire, AxisCamera("cam1", wire.url, user=None) as cam:
        with pytest.raises(BadReply) as err:
            cam.led_state()
        assert str(err.value).startswith("camera cam1: port.cgi answered ") and "output port 1" in str(err.value)
        assert "\n" not in str(err.value)
    wire.assert_complete()


def test_a_refusal_of_the_query_is_one_sentence():
    script = [("GET /axis-cgi/io/port.cgi?checkactive=3", None, "# Error: Invalid port '3'\r\n")]
    with ScriptedHTTP(script) as wire, AxisCamera("cam1", wire.url, user=None, led_port=3) as cam:
        with pytest.raises(BadReply, match=r"^camera cam1 refused /axis-cgi/io/port.cgi: Invalid port '3'$"):
            cam.led_state()
    wire.assert_complete()


def _body(server, path):
    with raw_request(server, path) as (_, reader):
        status, headers = read_head(reader)
        return status, headers, reader.read(int(headers["content-length"]))


def test_the_simulated_p1375_answers_the_state_as_the_firmware_and_the_driver_reads_it_back():
    with SimRig(n_cameras=1, seed=2, password=PASSWORD) as rig, rig.env():
        server = rig.servers["cam1"]
        with AxisCamera.from_config(rig.config().camera("cam1")) as cam:
            cam.led_off()
            assert cam.led_state() is False
            assert _body(server, "/axis-cgi/io/port.cgi?checkactive=1")[::2] == (
                b"HTTP/1.1 200 OK\r\n",
                b"port1=inactive\r\n",
            )
            cam.led_on()
            assert cam.led_state() is True
            assert _body(server, "/axis-cgi/io/port.cgi?checkactive=1")[2] == b"port1=active\r\n"
            # both ports at once (port 2 is the input), and a port the camera does not have
            assert _body(server, "/axis-cgi/io/port.cgi?checkactive=1,2")[2] == b"port1=active\r\nport2=inactive\r\n"
            assert _body(server, "/axis-cgi/io/port.cgi?checkactive=7")[2] == b"# Error: Invalid port '7'\r\n"
            # an action rule holds the output: the switch is answered OK, and the state says it did not take
            server.faults.led_held = True
            cam.led_off()
            assert rig.sources["cam1"].led_on() and cam.led_state() is True
            server.faults.led_held = False
            cam.led_off()
            assert cam.led_state() is False


def test_the_simulated_axis_211_answers_output_cgi_check_and_the_driver_reads_it_back():
    with SimRig(n_cameras=1, seed=2, firmware="vapix2", password=PASSWORD) as rig, rig.env():
        server = rig.servers["cam1"]
        with AxisCamera.from_config(rig.config().camera("cam1")) as cam:
            cam.led_on()
            assert cam.led_state() is True
            status, headers, body = _body(server, "/axis-cgi/io/output.cgi?check=1")
            assert (status, body) == (b"HTTP/1.0 200 OK\r\n", b"output1=1\r\n")
            cam.led_off()
            assert cam.led_state() is False and not rig.sources["cam1"].led_on()
            assert _body(server, "/axis-cgi/io/output.cgi?check=2")[2] == b"# Error: Invalid output '2'\r\n"
            assert _body(server, "/axis-cgi/io/port.cgi?checkactive=1")[0] == b"HTTP/1.0 404 Not Found\r\n"


def test_vts_camera_led_reads_the_switch_back_and_one_that_did_not_take_is_exit_4(tmp_path, capsys):
    with SimRig(n_cameras=1, seed=2, password=PASSWORD) as rig, rig.env():
        y = tmp_path / "rig.yaml"
        y.write_text(dump_rig(rig.config()))
        led = ["camera", "led", "--config", y, "cam1"]
        code, out, err = vts(capsys, *led, "on")
        assert (code, out.strip()) == (0, "cam1: LED on (output port 1): read back: on"), err
        rig.servers["cam1"].faults.led_held = True  # an action rule on the camera holds the output on
        code, out, err = vts(capsys, *led, "off")
        assert (code, out) == (4, ""), out
        assert err == (
            "vts: camera cam1 accepted the switch off but its LED output (port 1) still reads on after 1 s: "
            "the switch did not take (an action rule on the camera may hold the port)\n"
        )
        assert rig.sources["cam1"].led_on()
        code, out, err = vts(capsys, *led, "pulse", "200")
        assert code == 4 and err.startswith(
            "vts: camera cam1 accepted a pulse of 200 ms but its LED output (port 1) still reads on "
        ), err
        rig.servers["cam1"].faults.led_held = False
        code, out, err = vts(capsys, *led, "pulse", "200")
        assert (
            code == 0 and "OK" not in out and out.startswith("cam1: LED pulse 200 ms (output port 1): read back: ")
        ), out
        assert not rig.sources["cam1"].led_on()
