"""Who the console answers: the names it serves under, the origins its POSTs may come from, and
the peers that may talk to it in plain HTTP (docs/security.md, docs/decisions/0079-console-network.md).

* ``Reach``: the names (``localhost``, ``127.0.0.1``, ``::1``, ``--host`` when it is one
  address, the certificate's subjectAltNames, each ``--server-name``), whether the console
  serves HTTPS itself, and the proxy in front of it (``--behind-proxy``, ``--proxy ADDR``).
  ``Reach.local()`` is the console on this machine alone.
* ``HostGate`` (ASGI middleware, in front of every route, static files, event streams and the
  login page included): a request whose Host header is not one of those names is answered 400
  with a sentence. A page of another site that got its name resolved to this machine (DNS
  rebinding) reads nothing, the page token included.
* ``Reach.origin_ok``: an Origin (or a Referer's origin) is one of the console's own
  (scheme, name, port): the port is the one the request came in on (``scope["server"]``, not a
  header), or the one a ``--server-name NAME:PORT`` says, 443 through the proxy.
* ``PeerGate`` (ASGI middleware): with ``--proxy ADDR``, a connection from any other address
  than the proxy's and this machine's is refused (403 with a sentence): plain HTTP reaches
  nothing off this machine but the proxy. uvicorn's ``ProxyHeadersMiddleware`` then takes
  X-Forwarded-For/-Proto from the proxy only.
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass, field
from urllib.parse import urlsplit

from cryptography import x509
from starlette.responses import PlainTextResponse

from vts_hw.errors import UsageError

LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
#: the "every address" hosts, recognised to ask for a name to answer to (nothing is bound here)
WILDCARD_HOSTS = frozenset({"0.0.0.0", "::", ""})  # nosec B104: names to recognise, nothing binds to them
DEFAULT_PORTS = {"http": 80, "https": 443}
_LABEL = re.compile(r"(?!-)[a-z0-9-]{1,63}(?<!-)")
SHOWN_MAX = 80


def _label_ok(name: str) -> bool:
    return len(name) <= 253 and all(_LABEL.fullmatch(p) for p in name.split("."))


def parse_host(value: str) -> tuple[str, int | None] | None:
    """(name, port or None) of a Host header or an address ``NAME[:PORT]`` / ``[V6][:PORT]``:
    the name lower-case, an IPv6 address without its brackets; None when it is not one."""
    value = value.strip().lower()
    if value.startswith("["):
        end = value.find("]")
        if end < 0:
            return None
        name, rest = value[1:end], value[end + 1 :]
        try:
            if ipaddress.ip_address(name).version != 6:
                return None
        except ValueError:
            return None
    else:
        name, sep, rest = value.partition(":")
        rest = sep + rest
        if not name:
            return None
        try:
            ipaddress.ip_address(name)
        except ValueError:
            if not _label_ok(name):
                return None
    if not rest:
        return name, None
    if not rest.startswith(":") or not rest[1:].isdigit() or len(rest) > 6 or not 0 < int(rest[1:]) < 65536:
        return None
    return name, int(rest[1:])


def _shown(value: str) -> str:
    return repr(value[:SHOWN_MAX] + ("..." if len(value) > SHOWN_MAX else ""))


def server_name(value: str) -> tuple[str, int | None]:
    """A ``--server-name`` (``NAME``, ``NAME:PORT``, an address, ``[V6]:PORT``): (name, port), or
    UsageError in one sentence."""
    got = parse_host(value)
    if got is None or got[0] in WILDCARD_HOSTS:
        raise UsageError(
            f"--server-name {_shown(value)} is not a host name or address (NAME or NAME:PORT, "
            f"one name each, no wildcards)"
        )
    return got


def proxy_address(value: str) -> str:
    """The ``--proxy`` address (an IP address of one machine), normalised; else UsageError."""
    try:
        ip = ipaddress.ip_address(value.strip())
    except ValueError:
        raise UsageError(
            f"--proxy {_shown(value)} is not an IP address: give the address the reverse proxy connects from"
        ) from None
    if ip.is_unspecified or ip.is_multicast:
        raise UsageError(
            f"--proxy {value} is not the address of one machine: give the address the reverse proxy connects from"
        )
    return str(ip)


def cert_names(certfile: str) -> set[str]:
    """The DNS names and IP addresses of the certificate's subjectAltName (lower-case)."""
    try:
        with open(certfile, "rb") as f:
            cert = x509.load_pem_x509_certificate(f.read())
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except (OSError, ValueError, x509.ExtensionNotFound):  # (serve_checks.check_tls has said what is wrong)
        return set()
    names = {n.lower() for n in san.get_values_for_type(x509.DNSName) if "*" not in n}
    return names | {str(ip) for ip in san.get_values_for_type(x509.IPAddress)}


def _peer(host: str) -> str:
    """An address as compared: an IPv4-mapped IPv6 address as its IPv4 one."""
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return host
    mapped = getattr(ip, "ipv4_mapped", None)
    return str(mapped or ip)


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(_peer(host)).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True)
class Reach:
    """The names the console answers to and how browsers reach it (see the module docstring)."""

    #: names answered directly (on the port the request came in on)
    names: frozenset[str] = LOOPBACK_NAMES
    #: ``--server-name`` entries: (name, port or None)
    served_as: frozenset[tuple[str, int | None]] = frozenset()
    #: the console serves HTTPS itself
    tls: bool = False
    #: behind a TLS reverse proxy (the browsers' origin is https://NAME[:PORT] of a --server-name)
    proxied: bool = False
    #: the proxy's address when it is another machine (None: on this machine, over loopback)
    proxy: str | None = None
    _all: frozenset[str] = field(default=frozenset(), init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "_all", frozenset(self.names) | {n for n, _ in self.served_as})

    @classmethod
    def local(cls) -> Reach:
        """The console on this machine alone: the loopback names, plain HTTP."""
        return cls()

    @classmethod
    def build(
        cls,
        host: str,
        *,
        certfile: str | None = None,
        server_names=(),
        behind_proxy: bool = False,
        proxy: str | None = None,
    ) -> Reach:
        names = set(LOOPBACK_NAMES)
        h = parse_host(host if ":" not in host or host.startswith("[") else f"[{host}]")
        if h is not None and h[0] not in WILDCARD_HOSTS:
            names.add(h[0])
        if certfile:
            names |= cert_names(certfile)
        served = frozenset(server_name(s) for s in server_names)
        return cls(
            names=frozenset(names),
            served_as=served,
            tls=bool(certfile),
            proxied=bool(behind_proxy or proxy),
            proxy=proxy_address(proxy) if proxy else None,
        )

    def off_loopback_names(self) -> set[str]:
        return set(self._all) - LOOPBACK_NAMES

    # -- the Host header ----------------------------------------------------------------------------
    def answers(self, host_header: str | None) -> str:
        """'' when the console answers a request with this Host header; else why not (a sentence)."""
        if host_header is None:
            return "refused: a request without a Host header (the name the console was reached by)"
        got = parse_host(host_header)
        if got is None:
            return f"refused: the Host header {_shown(host_header)} is not a host name"
        if got[0] not in self._all:
            return (
                f"refused: this console does not answer to the name {_shown(got[0])}: open it at the address "
                f"it printed, or start it with --server-name for that name"
            )
        return ""

    # -- origins ------------------------------------------------------------------------------------------
    def origin_ok(self, origin: str, server_port: int | None) -> bool:
        """Whether ``origin`` (``scheme://name[:port]``) is one of the console's own, for a request
        that came in on ``server_port``."""
        try:
            parts = urlsplit(origin)
            scheme, name, port = parts.scheme, (parts.hostname or ""), parts.port
        except ValueError:
            return False
        if scheme not in DEFAULT_PORTS or not name or parts.path not in ("", "/") or parts.username is not None:
            return False
        port = port if port is not None else DEFAULT_PORTS[scheme]
        direct = "https" if self.tls else "http"
        if scheme == direct and name in self.names and port == server_port:
            return True
        for n, p in self.served_as:  # through the proxy: https on its port; else as the console serves
            if n == name and (
                (scheme, port) == ("https", p or 443) if self.proxied else (scheme, port) == (direct, p or server_port)
            ):
                return True
        return False

    def peer_ok(self, peer: str | None) -> bool:
        """Whether a connection from ``peer`` may be served: this machine's, or the proxy's (with --proxy)."""
        if self.proxy is None or peer is None:
            return True
        return _is_loopback(peer) or _peer(peer) == self.proxy

    def trusted_proxies(self) -> list[str]:
        """The addresses whose X-Forwarded-For/-Proto are believed: the proxy's, else this machine's."""
        return [self.proxy] if self.proxy else ["127.0.0.1", "::1"]


class HostGate:
    """ASGI middleware: a request whose Host is not one of ``reach``'s names is answered 400."""

    def __init__(self, app, reach: Reach):
        self.app, self.reach = app, reach

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        hosts = [v.decode("latin-1") for k, v in scope.get("headers", ()) if k == b"host"]
        why = (
            "refused: a request with more than one Host header"
            if len(hosts) > 1
            else self.reach.answers(hosts[0] if hosts else None)
        )
        if not why:
            await self.app(scope, receive, send)
        elif scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008})
        else:
            await PlainTextResponse(why, status_code=400)(scope, receive, send)


class PeerGate:
    """ASGI middleware: with ``--proxy ADDR``, only the proxy and this machine are served."""

    def __init__(self, app, reach: Reach):
        self.app, self.reach = app, reach

    async def __call__(self, scope, receive, send):
        client = scope.get("client")
        if scope["type"] not in ("http", "websocket") or self.reach.peer_ok(client[0] if client else None):
            await self.app(scope, receive, send)
        elif scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008})
        else:
            await PlainTextResponse(
                f"refused: this console is served to other computers through its HTTPS proxy only ({self.reach.proxy})",
                status_code=403,
            )(scope, receive, send)


__all__ = [
    "Reach",
    "HostGate",
    "PeerGate",
    "parse_host",
    "server_name",
    "proxy_address",
    "cert_names",
    "LOOPBACK_NAMES",
    "WILDCARD_HOSTS",
]
