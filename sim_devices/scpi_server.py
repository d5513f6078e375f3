"""A SCPI instrument on a TCP socket on 127.0.0.1, as LAN instruments serve SCPI on port 5025.

:class:`SimFunctionGenerator` serves a :class:`~.keysight_33500.Keysight33500` to any number of
clients, one thread each: every line a client sends (ending in ``\\n``; a ``\\r`` before it is
dropped) goes to the instrument, and each response goes back ending in ``\\n``. A VISA client
opens it as ``TCPIP::127.0.0.1::<port>::SOCKET`` (pyvisa with pyvisa-py, or any VISA), with
``\\n`` as read and write termination, exactly as a real 33500 on the LAN. The port is chosen by
the OS. The instrument, and so its state, lives as long as the server: separate ``vts trigger``
commands see the settings the previous one left.

Faults for tests: :meth:`go_silent` (the instrument reads commands but answers nothing, so a
query times out), :meth:`go_trickle` (every reply a byte at a time), :meth:`stop` (the port
closes: connections are cut and new ones refused).
:meth:`log_to` appends every output change to a CSV file (host time, channel, on/off, the wave),
for whoever needs to know when the wave ran.
"""

from __future__ import annotations

import csv
import socket
import socketserver
import threading
import time
from dataclasses import astuple, fields
from pathlib import Path
from typing import TextIO

from vts_hw.files import open_writable
from vts_hw.sim_devices.keysight_33500 import Keysight33500, OutputEvent

MAX_LINE = 64 * 1024  # a longer line without a terminator is dropped (an input buffer)
OUTPUT_LOG_HEADER = [f.name for f in fields(OutputEvent)]


class _Handler(socketserver.BaseRequestHandler):
    def handle(self) -> None:
        srv: SimFunctionGenerator = self.server.owner  # type: ignore[attr-defined]
        sock: socket.socket = self.request
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        srv._track(sock, True)
        buf = b""
        try:
            while True:
                try:
                    chunk = sock.recv(4096)
                except OSError:
                    return
                if not chunk:
                    return
                buf += chunk
                *lines, buf = buf.split(b"\n")
                if len(buf) > MAX_LINE:
                    buf = b""
                for raw in lines:
                    text = raw.rstrip(b"\r").decode("latin-1")
                    reply = srv.instrument.execute(text)
                    if reply is not None and not srv.silent.is_set():
                        try:
                            _answer(srv, sock, reply.encode("latin-1") + b"\n")
                        except OSError:
                            return
        finally:
            srv._track(sock, False)


def _answer(srv: SimFunctionGenerator, sock: socket.socket, data: bytes) -> None:
    """Send a reply: at once, or (:meth:`SimFunctionGenerator.go_trickle`) a byte at a time."""
    if not srv.trickle_s:
        sock.sendall(data)
        return
    for k in range(len(data)):
        sock.sendall(data[k : k + 1])
        if srv._stopping.wait(srv.trickle_s):
            return


class _Server(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True


class SimFunctionGenerator:
    """A simulated Keysight 33522B served on 127.0.0.1 (``port=0``: the OS picks one)."""

    def __init__(self, instrument: Keysight33500 | None = None, port: int = 0, clock=time.time):
        self.instrument = instrument or Keysight33500(clock=clock)
        self.port = port
        self.silent = threading.Event()
        self.trickle_s = 0.0
        self._stopping = threading.Event()
        self._server: _Server | None = None
        self._thread: threading.Thread | None = None
        self._clients: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._log_file: TextIO | None = None
        self._log_error: str | None = None

    @property
    def resource(self) -> str:
        """The VISA address a client opens."""
        return f"TCPIP::127.0.0.1::{self.port}::SOCKET"

    def start(self) -> SimFunctionGenerator:
        self._stopping.clear()
        self._server = _Server(("127.0.0.1", self.port), _Handler)
        self._server.owner = self  # type: ignore[attr-defined]
        self.port = self._server.server_address[1]
        self._thread = threading.Thread(
            target=self._server.serve_forever, args=(0.05,), name=f"sim-33500-{self.port}", daemon=True
        )
        self._thread.start()
        return self

    def stop(self) -> None:
        """Close the port: connected clients are cut off, new ones refused. The instrument keeps
        its state (``start()`` again serves it on the same port)."""
        self._stopping.set()
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
        with self._lock:
            clients, self._clients = list(self._clients), set()
        for s in clients:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()
        if self._thread is not None:
            self._thread.join(5)
            self._thread = None
        if self._log_file is not None:
            self.instrument.listeners.remove(self._write_event)
            self._log_file.close()
            self._log_file = None

    def go_trickle(self, seconds_per_byte: float = 1.0) -> None:
        """Every reply a byte every ``seconds_per_byte`` seconds (0: at once again): an
        instrument behind a sick link. A client that times each read alone waits for ever."""
        self.trickle_s = float(seconds_per_byte)

    def go_silent(self, silent: bool = True) -> None:
        """The instrument goes on taking commands but answers no query (a hung instrument)."""
        if silent:
            self.silent.set()
        else:
            self.silent.clear()

    def clients(self) -> int:
        with self._lock:
            return len(self._clients)

    def log_to(self, path: str | Path) -> Path:
        """Append every output event, past and future, to the CSV file ``path``."""
        path = Path(path)
        with self.instrument.lock:
            new = not path.exists() or path.stat().st_size == 0
            self._log_file = open_writable(path, "a", newline="", encoding="utf-8")  # a regular file only
            self._log_writer = csv.writer(self._log_file)
            if new:
                self._log_writer.writerow(OUTPUT_LOG_HEADER)
            for ev in self.instrument.events:
                self._write_event(ev)
            self.instrument.listeners.append(self._write_event)
        return path

    def _write_event(self, ev: OutputEvent) -> None:
        if self._log_file is None or self._log_error:
            return
        try:
            row = list(astuple(ev))
            row[0] = f"{ev.host_time:.6f}"
            row[2] = int(ev.output)
            self._log_writer.writerow(row)
            self._log_file.flush()
        except OSError as e:  # a full disk must not stop the instrument; the log says so no more
            self._log_error = str(e)

    def _track(self, sock: socket.socket, add: bool) -> None:
        with self._lock:
            (self._clients.add if add else self._clients.discard)(sock)

    def __enter__(self) -> SimFunctionGenerator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def read_output_log(path: str | Path) -> list[OutputEvent]:
    """The events a :meth:`SimFunctionGenerator.log_to` file holds."""
    with open(path, newline="", encoding="utf-8") as f:
        return [
            OutputEvent(
                float(r["host_time"]),
                int(r["channel"]),
                r["output"] == "1",
                r["function"],
                float(r["frequency_hz"]),
                float(r["duty_percent"]),
                float(r["high_v"]),
                float(r["low_v"]),
            )
            for r in csv.DictReader(f)
        ]
