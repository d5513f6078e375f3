"""An Axis camera's I/O output port, where the LED ring hangs: switched, pulsed and read back.

``port.cgi?action=1:/`` (on), ``1:\\`` (off), ``1:/300\\`` (a 300 ms pulse), the action characters
percent-encoded; ``port.cgi?checkactive=N`` reads the state. Firmware before 5.00 (VAPIX 2)
answers 404 on ``port.cgi`` and is asked on ``io/output.cgi`` (``check=N``) instead, which is
remembered. :class:`AxisIOPort` is the :class:`~vts_hw.camera.Illumination` role of an HTTP
camera (:class:`~vts_hw.drivers.axis_client.AxisClient`) with a ``led_port``: the ``axis`` kind,
and the ``mjpeg`` kind with ``led: vapix``.
"""

from __future__ import annotations

from urllib.parse import quote

from vts_hw.drivers.axis_client import AxisClient
from vts_hw.drivers.axis_errors import BadReply, NotFound


class AxisIOPort(AxisClient):
    """The LED on the camera's I/O output port ``led_port`` (1-based), over the HTTP client."""

    led_port: int
    _output_cgi = "/axis-cgi/io/port.cgi"  # io/output.cgi on VAPIX 2 firmware, once found out

    def _io(self, ask) -> str:
        """``port.cgi``'s answer to ``ask(cgi)`` (a path and its query), else ``output.cgi``'s
        (firmware before 5.00: port.cgi answers 404), remembered for the next call."""
        try:
            return self._text(*ask(self._output_cgi))
        except NotFound:
            if self._output_cgi == "/axis-cgi/io/output.cgi":
                raise
            self._output_cgi = "/axis-cgi/io/output.cgi"
            return self._text(*ask(self._output_cgi))

    def _port(self, action: str) -> None:
        # port.cgi (output.cgi on VAPIX 2) wants the action characters percent-encoded (/ and \)
        query = "?action=" + quote(action, safe=":")
        text = self._io(lambda cgi: (cgi + query,))
        if text.strip() and not text.strip().upper().startswith("OK"):
            cgi = self._output_cgi.rsplit("/", 1)[-1]
            raise BadReply(self.name, f"camera {self.name}: {cgi} answered {text.strip()[:80]!r}")

    def led_on(self) -> None:
        self._port(f"{self.led_port}:/")

    def led_off(self) -> None:
        self._port(f"{self.led_port}:\\")

    def led_pulse(self, ms: int) -> None:
        if not 1 <= int(ms) <= 60000:
            raise ValueError("LED pulse must be 1 to 60000 ms")
        self._port(f"{self.led_port}:/{int(ms)}\\")

    def led_state(self) -> bool | None:
        """Whether the LED's output port is active now, as the camera says: ``port.cgi?checkactive=N``
        answers ``portN=active`` or ``portN=inactive``; VAPIX 2's ``output.cgi?check=N``, ``outputN=1`` or 0."""
        n = self.led_port
        got = self._io(lambda cgi: (cgi, {"checkactive" if cgi.endswith("port.cgi") else "check": n})).strip()
        states = {f"port{n}=active": True, f"port{n}=inactive": False, f"output{n}=1": True, f"output{n}=0": False}
        if got not in states:
            cgi = self._output_cgi.rsplit("/", 1)[-1]
            raise BadReply(
                self.name,
                f"camera {self.name}: {cgi} answered {got[:80]!r} when asked the state of output port {n} (the LED)",
            )
        return states[got]


__all__ = ["AxisIOPort"]
