"""A scripted serial port for byte-exact protocol tests of the trigger-box driver.

:func:`expected_protocol` hands the driver a :class:`ScriptedSerial` (through its
``serial_factory`` argument) that knows, in order, every line the driver must write and the
bytes the box answers to each. It fails at the first byte written that differs, and on leaving
the block if any scripted exchange was never made. An answer may also be an exception, raised
when the driver writes (``Fail(exc, on="write")``) or reads (``Fail(exc)``) that exchange.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass

from vts_hw.drivers.trigger_box import TriggerBox

PORT = "/dev/ttyFAKE0"


# ---- the scripted port ----------------------------------------------------------------------------


class ProtocolMismatch(AssertionError):
    pass


@dataclass
class Fail:
    """Raise ``exc`` when the driver writes (``on="write"``) or reads the answer of this exchange."""

    exc: BaseException
    on: str = "read"


class ScriptedSerial:
    """Stands where a ``serial.Serial`` would; checks every byte the driver writes."""

    def __init__(self, pairs, port, **kwargs):
        for p in pairs:
            if not (
                isinstance(p, tuple) and len(p) == 2 and isinstance(p[0], bytes) and isinstance(p[1], (bytes, Fail))
            ):
                raise TypeError(f"each pair is (bytes written, bytes answered or Fail), not {p!r}")
        self.pairs = list(pairs)
        self.port = port
        self.kwargs = kwargs
        self.done = 0  # pairs completed
        self.written = b""  # bytes of the current pair written so far
        self.rx = bytearray()  # bytes the "box" sent that the driver has not read
        self.pending_fail: BaseException | None = None
        self.is_open = True
        self.errors: list[str] = []  # every mismatch, even if the driver swallowed the exception

    def _mismatch(self, text: str):
        self.errors.append(text)
        raise ProtocolMismatch(text)

    # what the driver calls
    def write(self, data: bytes) -> int:
        if not self.is_open:
            self._mismatch(f"write {data!r} after close")
        if not isinstance(data, bytes):
            self._mismatch(f"write of {type(data).__name__}, not bytes: {data!r}")
        if self.done >= len(self.pairs):
            self._mismatch(f"{data!r} written after the script's {len(self.pairs)} exchanges")
        want, answer = self.pairs[self.done]
        if isinstance(answer, Fail) and answer.on == "write":
            self.done += 1
            raise answer.exc
        sofar = self.written + data
        if not want.startswith(sofar):
            self._mismatch(f"exchange {self.done + 1}: expected {want!r}, got {sofar!r}")
        self.written = sofar
        if sofar == want:
            self.written = b""
            self.done += 1
            if isinstance(answer, Fail):
                self.pending_fail = answer.exc
            else:
                self.rx += answer
        return len(data)

    def _maybe_fail(self):
        if self.pending_fail is not None:
            exc, self.pending_fail = self.pending_fail, None
            raise exc

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        self._maybe_fail()
        i = self.rx.find(expected)
        n = len(self.rx) if i < 0 else i + len(expected)
        if size is not None:
            n = min(n, size)
        out = bytes(self.rx[:n])
        del self.rx[:n]
        return out  # no terminator: what a real port returns when the timeout runs out

    def read(self, size: int = 1) -> bytes:
        self._maybe_fail()
        out = bytes(self.rx[:size])
        del self.rx[:size]
        return out

    @property
    def in_waiting(self) -> int:
        self._maybe_fail()
        return len(self.rx)

    def reset_input_buffer(self) -> None:
        self.rx.clear()

    def close(self) -> None:
        self.is_open = False

    # what the test calls
    def assert_complete(self) -> None:
        if self.errors:
            raise ProtocolMismatch(self.errors[0])
        if self.written:
            raise ProtocolMismatch(f"a partial line {self.written!r} was written")
        if self.done != len(self.pairs):
            raise ProtocolMismatch(
                f"{len(self.pairs) - self.done} exchange(s) never made, first {self.pairs[self.done]!r}"
            )


class FakeClock:
    """Host time that moves only when told (each read may advance it by ``step``)."""

    def __init__(self, t=1_700_000_000.0, step=0.0):
        self.t = t
        self.step = step

    def __call__(self) -> float:
        t = self.t
        self.t += self.step
        return t

    def sleep(self, s: float) -> None:
        self.t += s


@contextmanager
def expected_protocol(pairs, **kwargs):
    """A TriggerBox on a ScriptedSerial; on leaving, every scripted pair must have been used."""
    made = {}

    def factory(port, **kw):
        made["fake"] = ScriptedSerial(pairs, port, **kw)
        return made["fake"]

    kwargs.setdefault("clock", FakeClock())
    kwargs.setdefault("sleep", getattr(kwargs["clock"], "sleep", lambda s: None))
    # no heartbeat thread writing at its own moments: a test calls box.heartbeat.beat_if_due()
    kwargs.setdefault("heartbeat", False)
    kwargs.setdefault("monotonic", FakeClock(0.0))
    box = TriggerBox(PORT, serial_factory=factory, **kwargs)
    box.fake = made["fake"]
    yield box
    made["fake"].assert_complete()


def lines(*pairs):
    """('CMD', 'REPLY') text pairs as wire bytes, each with its "\\n"."""
    return [(c.encode() + b"\n", r.encode() + b"\n") for c, r in pairs]


STATUS_OFF = [
    ("OUTP?", "OFF"),
    ("FREQ?", "10"),
    ("DUTY?", "0.25"),
    ("EDGES?", "0,0,0"),
    ("WDOG?", "10.000000,IDLE,0"),
    ("SYST:ERR?", '0,"No error"'),
]
