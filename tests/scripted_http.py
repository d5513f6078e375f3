"""Byte-exact HTTP exchanges for a driver's tests, in the style of tests/protocol.py: a server on
127.0.0.1 that is given the exact requests the driver must make, in order -- ``(method and
target, body or None, reply)`` -- answers each with its reply, and records the first request
that differs (answered 500, so the driver fails there too). ``assert_complete()`` fails at a
mismatch and at any exchange never made; ``lines`` keeps every request line as sent
(``GET /path?query HTTP/1.1``). A reply is text or bytes (200), or ``(status, body)``."""

from __future__ import annotations

import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


class ScriptedHTTP:
    def __init__(self, exchanges):
        self.exchanges = list(exchanges)
        self.done = 0
        self.mismatch: str | None = None
        self.lines: list[str] = []
        script = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def _one(self):
                n = int(self.headers.get("Content-Length") or 0)
                body = self.rfile.read(n) if n else b""
                got = f"{self.command} {self.path}"
                script.lines.append(self.requestline)
                status, reply, ctype = script._answer(got, body)
                data = reply.encode() if isinstance(reply, str) else reply
                self.send_response(status)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            do_GET = do_POST = _one

            def log_message(self, *a):
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)

    def _answer(self, got: str, body: bytes):
        i = self.done
        if self.mismatch is not None:
            return 500, "after a mismatch", "text/plain"
        if i >= len(self.exchanges):
            self.mismatch = f"request {i + 1}: {got!r} after the script's {len(self.exchanges)} exchanges"
            return 500, "no more", "text/plain"
        want, want_body, reply = self.exchanges[i]
        if got != want or (want_body is not None and body != want_body):
            self.mismatch = f"request {i + 1}: expected {want!r} {want_body!r}, got {got!r} {body!r}"
            return 500, "mismatch", "text/plain"
        self.done += 1
        if isinstance(reply, tuple):
            return reply[0], reply[1], "text/html"
        json_like = reply.lstrip().startswith(b"{" if isinstance(reply, bytes) else "{")
        return 200, reply, "application/json" if json_like else "text/plain"

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.httpd.server_address[1]}"

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.httpd.shutdown()
        self.httpd.server_close()

    def assert_complete(self) -> None:
        assert self.mismatch is None, self.mismatch
        assert self.done == len(self.exchanges), (
            f"{len(self.exchanges) - self.done} exchange(s) never made, first {self.exchanges[self.done][0]!r}"
        )
