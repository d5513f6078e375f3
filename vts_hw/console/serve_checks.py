"""What `vts console` refuses before anything is read, bound or opened, one sentence each (exit
2): the host it is asked to serve on, its certificate and key, and (once the store is read) a
console that needs a login with no user to log in. Apart from the server (serve.py), so that a
refusal loads no page of the console.
"""

from __future__ import annotations

import ipaddress
import os
import ssl

from vts_hw.console.hosts import WILDCARD_HOSTS, Reach
from vts_hw.errors import UsageError

LOOPBACK_NAMES = ("localhost",)
HOW_TO_ADD = "add one with `vts console user add NAME --role physicist`"


class NotOnLoopback(UsageError):
    """Serving off this machine needs users (and HTTPS) that are not there."""


def is_loopback(host: str) -> bool:
    if host.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_host(
    host: str,
    *,
    certfile: str | None = None,
    keyfile: str | None = None,
    behind_proxy: bool = False,
    proxy: str | None = None,
    server_names=(),
) -> Reach:
    """What can be refused from the command line alone (before the store or the rig is read), in
    one sentence each (exit 2): --certfile without --keyfile, a certificate or key that is not one
    (check_tls); plain HTTP anywhere but on this machine and to the proxy (a login never travels
    in clear: off this machine HTTPS, or a TLS proxy on this machine, or --proxy ADDR, the only
    other computer served); a bad --proxy or --server-name; behind a proxy without the name the
    browsers reach it under; on every address (0.0.0.0) without any name to answer to. The names
    and origins the console then answers to (hosts.Reach)."""
    tls = check_tls(certfile, keyfile)
    reach = Reach.build(
        host, certfile=certfile if tls else None, server_names=server_names, behind_proxy=behind_proxy, proxy=proxy
    )
    if not is_loopback(host) and not tls and reach.proxy is None:
        raise NotOnLoopback(
            f"refused to serve the console on {host} in plain HTTP: off this machine it needs users "
            f"and login over HTTPS: give --certfile and --keyfile, or serve it behind a TLS reverse "
            f"proxy on this machine (a loopback --host and --behind-proxy) or at --proxy ADDR "
            f"(docs/operate/console.md: Console users and HTTPS)"
        )
    if reach.proxied and not reach.served_as:
        raise UsageError(
            "refused: behind a proxy the console needs the name the browsers reach the proxy under: "
            "give --server-name NAME (NAME:PORT when not 443)"
        )
    if host in WILDCARD_HOSTS and not reach.off_loopback_names():
        raise NotOnLoopback(
            f"refused to serve the console on every address ({host}) with no name to answer to from "
            f"other computers: give --server-name NAME (the name or address they reach this one "
            f"by), or a certificate naming it"
        )
    return reach


def login_required(host: str, login: bool = False, behind_proxy: bool = False) -> bool:
    """Whether the pages need a login: off this machine, behind a proxy (reached from elsewhere
    through it; --proxy counts as --behind-proxy), or asked for with --login."""
    return bool(login or behind_proxy or not is_loopback(host))


def check_users(host: str, n_users: int, where: str, why_not: str = "") -> None:
    """Refuse (exit 2) a console that needs a login when the store has no user who may log in."""
    if n_users:
        return
    what = (
        f"the results store could not be read for its users ({why_not})"
        if why_not
        else f"the results store {where} has no console user who may log in"
    )
    if is_loopback(host):
        raise UsageError(f"refused to require a login (--login, --behind-proxy): {what}; {HOW_TO_ADD}")
    raise NotOnLoopback(
        f"refused to serve the console on {host}: off this machine it needs users and login, and {what}; {HOW_TO_ADD}"
    )


def check_tls(certfile: str | None, keyfile: str | None) -> bool:
    """True when the console serves HTTPS with this certificate and key; each file is checked now
    (readable, a PEM certificate, its private key, not encrypted): a bad one is one sentence naming it."""
    if not certfile and not keyfile:
        return False
    if not certfile or not keyfile:
        raise UsageError("--certfile and --keyfile go together: give both (the certificate and its private key)")
    for opt, f in (("--certfile", certfile), ("--keyfile", keyfile)):
        if not os.path.isfile(f):
            raise UsageError(f"{f}: no such file ({opt})")
        if not os.access(f, os.R_OK):
            raise UsageError(f"{f}: cannot be read by this user ({opt})")
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    try:
        ctx.load_verify_locations(cafile=certfile)
    except (ssl.SSLError, ValueError):
        raise UsageError(f"{certfile}: not a PEM certificate (--certfile)") from None
    asked = []

    def no_passphrase():
        asked.append(1)
        return b""

    try:
        ctx.load_cert_chain(certfile, keyfile, password=no_passphrase)
    except (ssl.SSLError, ValueError) as exc:
        if asked:
            raise UsageError(
                f"{keyfile}: the private key is encrypted: give it unencrypted, readable by this user only (--keyfile)"
            ) from None
        if "KEY_VALUES_MISMATCH" in str(exc) or "key values mismatch" in str(exc):
            raise UsageError(f"{keyfile}: not the private key of the certificate {certfile} (--keyfile)") from None
        raise UsageError(f"{keyfile}: not a PEM private key (--keyfile)") from None
    return True


__all__ = ["NotOnLoopback", "check_host", "check_tls", "check_users", "is_loopback", "login_required"]
