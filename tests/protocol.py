"""Byte-exact protocol checks for message-based (SCPI) drivers, in the style of PyMeasure's
``expected_protocol``.

A :class:`ProtocolResource` stands where an open pyvisa resource would: it is given the exact
exchanges the driver must make, in order — ``(command, reply)`` for a query, ``(command, None)``
for a write — and fails at the first command that differs, at a reply that is read without
having been asked for, at a reply left unread, and (on leaving :func:`expected_protocol`) at
any exchange the driver never made.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager


class ProtocolMismatch(AssertionError):
    pass


class ProtocolResource:
    """A stand-in for ``pyvisa.resources.MessageBasedResource`` that checks every exchange."""

    read_termination = "\n"
    write_termination = "\n"

    def __init__(self, exchanges: Sequence[tuple[str, str | None]], resource_name: str = "PROTOCOL::INSTR"):
        for ex in exchanges:
            if not (
                isinstance(ex, tuple)
                and len(ex) == 2
                and isinstance(ex[0], str)
                and (ex[1] is None or isinstance(ex[1], str))
            ):
                raise TypeError(f"each exchange is (command, reply or None), not {ex!r}")
        self.exchanges = list(exchanges)
        self.resource_name = resource_name
        self.sent: list[str] = []  # every command, as written
        self.done = 0  # exchanges completed
        self._reply: str | None = None  # the reply waiting to be read
        self.timeout = 2000
        self.closed = False

    # what the driver calls
    def write(self, message: str) -> int:
        if self.closed:
            raise ProtocolMismatch(f"write {message!r} after close")
        if self._reply is not None:
            raise ProtocolMismatch(
                f"write {message!r} while the reply {self._reply!r} to {self.sent[-1]!r} was never read"
            )
        if not isinstance(message, str) or not message.isascii() or "\n" in message:
            raise ProtocolMismatch(f"a command must be one ASCII line without its terminator, not {message!r}")
        self.sent.append(message)
        i = self.done
        if i >= len(self.exchanges):
            raise ProtocolMismatch(
                f"exchange {i + 1}: {message!r} sent, but the protocol ended after {len(self.exchanges)} exchanges"
            )
        want, reply = self.exchanges[i]
        if message != want:
            raise ProtocolMismatch(f"exchange {i + 1}: expected {want!r}, got {message!r}")
        if reply is None:
            self.done += 1
        else:
            self._reply = reply
        return len(message) + len(self.write_termination)

    def read(self) -> str:
        if self._reply is None:
            raise ProtocolMismatch(f"read with no reply due (last command {self.sent[-1:]!r})")
        reply, self._reply = self._reply, None
        self.done += 1
        return reply

    def query(self, message: str) -> str:
        self.write(message)
        if self._reply is None:
            raise ProtocolMismatch(
                f"exchange {self.done}: {message!r} was queried, but the protocol expects no reply to it"
            )
        return self.read()

    def close(self) -> None:
        self.closed = True

    # what the test calls
    def assert_complete(self) -> None:
        if self._reply is not None:
            raise ProtocolMismatch(f"the reply {self._reply!r} to {self.sent[-1]!r} was never read")
        if self.done != len(self.exchanges):
            left = self.exchanges[self.done :]
            raise ProtocolMismatch(f"{len(left)} exchange(s) never made, first {left[0]!r}")


@contextmanager
def expected_protocol(cls, exchanges: Sequence[tuple[str, str | None]], **kwargs) -> Iterator:
    """``cls(ProtocolResource(exchanges), **kwargs)``; checks on exit that every exchange was made.

    Include what the constructor exchanges (for example ``*IDN?``) at the start of ``exchanges``.
    """
    fake = ProtocolResource(exchanges)
    inst = cls(fake, **kwargs)
    yield inst
    fake.assert_complete()
