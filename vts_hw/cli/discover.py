"""`vts discover`: the Axis cameras on the network, as they announce themselves."""

from __future__ import annotations

import ipaddress
import sys

import click

from vts_hw.cli import cli
from vts_hw.cli.common import OutputFile, PositiveSeconds, echo_json, json_option

DEFAULT_PASSWORD_ENV = "VTS_CAMERA_PASSWORD"


def _ipv4(ctx, param, values):
    for v in values:
        try:
            ipaddress.IPv4Address(v)
        except ValueError:
            raise click.BadParameter(f"{v!r} is not an IPv4 address of this host (e.g. 192.168.10.2)") from None
    return list(values)


@cli.command()
@click.option(
    "-o",
    "--output",
    type=OutputFile(),
    default=None,
    help="Write a rig.yaml skeleton for the cameras found (never over an existing file).",
)
@click.option(
    "--timeout",
    type=PositiveSeconds(max=120),
    default=5.0,
    show_default=True,
    help="How long to listen for announcements, in seconds.",
)
@click.option(
    "--interface",
    "interfaces",
    multiple=True,
    callback=_ipv4,
    metavar="ADDRESS",
    help="Search from this IPv4 address of this host only (repeatable; default: every interface).",
)
@click.option("--user", default="root", show_default=True, help="User to confirm each camera with over VAPIX.")
@click.option(
    "--password-env",
    default=DEFAULT_PASSWORD_ENV,
    show_default=True,
    metavar="NAME",
    help="Environment variable holding the cameras' password (and written into the skeleton).",
)
@json_option
def discover(output, timeout, interfaces, user, password_env, as_json) -> None:
    """Find the Axis cameras on the network as they announce themselves.

    Listens for DNS-SD over mDNS (_axis-video._tcp) and sends an SSDP M-SEARCH, then asks
    each camera found for its model, serial number and firmware over VAPIX (basicdeviceinfo,
    or the Brand and Properties parameters of older firmware) to confirm what it announced.
    Prints a table; with -o writes a rig.yaml skeleton (cam1, cam2, ... in address order)
    that `vts camera setup --all` then completes.

    \b
    Exit status: 0 every camera found was confirmed; 2 bad input (-o names a file that
    exists: nothing is searched); 3 the skeleton could not be written; 4 no camera found, or
    a camera could not be confirmed (the skeleton is still written, saying so per camera).
    """
    from vts_hw.drivers.discovery import confirm, search
    from vts_hw.errors import DeviceError
    from vts_hw.rig_file import refuse_existing, skeleton, write_new

    if not password_env.isidentifier():
        raise click.BadParameter(f"{password_env!r} is not an environment variable name", param_hint="--password-env")
    if output:
        refuse_existing(output)
    if not as_json:
        where = ", ".join(interfaces) if interfaces else "every interface"
        click.echo(f"listening {timeout:g} s on {where} for Axis cameras (mDNS _axis-video._tcp, SSDP) ...", err=True)
    found = search(timeout, interfaces or None)
    found = [confirm(f, user, password_env) for f in found]
    rows = [
        {
            "name": f"cam{i}",
            "host": f.host,
            "port": f.port,
            "scheme": f.scheme,
            "model": f.model,
            "serial": f.serial,
            "firmware": f.firmware,
            "confirmed": f.confirmed,
            "announced_by": list(f.sources),
            "problem": f.problem,
            "notes": f.notes,
        }
        for i, f in enumerate(found, 1)
    ]
    written = None
    if output and rows:
        written = write_new(output, skeleton(rows, password_env=password_env, user=user))
    if as_json:
        echo_json({"cameras": rows, "written": str(written) if written else None})
    else:
        _table(rows)
        if written:
            click.echo(f"{written}: a rig.yaml for {len(rows)} camera(s); check it, then `vts camera setup --all`")
    if not rows:
        raise DeviceError(
            f"no Axis camera announced itself within {timeout:g} s on "
            f"{', '.join(interfaces) if interfaces else 'any interface'}"
            + (f"; {output} was not written" if output else "")
        )
    unconfirmed = [r for r in rows if not r["confirmed"]]
    for r in unconfirmed:
        click.echo(f"vts: {r['name']} ({r['host']}:{r['port']}) not confirmed: {r['problem']}", err=True)
    if unconfirmed:
        sys.exit(4)


def _table(rows: list[dict]) -> None:
    head = ("name", "address", "model", "serial", "firmware", "announced by", "VAPIX")
    body = [
        (
            r["name"],
            f"{r['host']}:{r['port']}",
            r["model"] or "?",
            r["serial"] or "?",
            r["firmware"] or "?",
            "+".join(r["announced_by"]),
            "confirmed" if r["confirmed"] else "NOT confirmed",
        )
        for r in rows
    ]
    widths = [max(len(str(x)) for x in col) for col in zip(head, *body)]
    for line in (head, *body):
        click.echo("  ".join(str(x).ljust(w) for x, w in zip(line, widths)).rstrip())
    for r in rows:
        for note in r["notes"]:
            click.echo(f"  note: {r['name']}: {note}")
