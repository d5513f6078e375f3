"""`vts console`: serve the room console (a local web page) for the rig; `vts console user ...`:
its users."""

from __future__ import annotations

import os

import click

from vts_hw.cli import cli
from vts_hw.cli.common import (
    PositiveSeconds,
    ask_password,
    config_option,
    echo_json,
    json_option,
    rig_if_any,
    store_target,
)
from vts_hw.errors import UsageError


@cli.group(invoke_without_command=True)
@config_option
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="Address to serve on. Off this machine (not 127.0.0.1, ::1, localhost) the console needs "
    "users in the results store (`vts console user add`) and HTTPS: --certfile/--keyfile, or a TLS "
    "reverse proxy at --proxy ADDR; else it is refused (exit 2).",
)
@click.option(
    "--port",
    type=click.IntRange(0, 65535),
    default=8040,
    show_default=True,
    help="Port to serve on (0: any free one; the address is printed).",
)
@click.option("--login", is_flag=True, help="Require a login on this machine too (the users of the results store).")
@click.option(
    "--certfile",
    type=click.Path(dir_okay=False),
    default=None,
    help="Serve HTTPS with this PEM certificate (with --keyfile).",
)
@click.option(
    "--keyfile",
    type=click.Path(dir_okay=False),
    default=None,
    help="The certificate's PEM private key, unencrypted (with --certfile).",
)
@click.option(
    "--behind-proxy",
    is_flag=True,
    help="A TLS reverse proxy (nginx, Caddy) on this machine serves the console to others: --host "
    "stays on loopback, login required, the session cookie Secure, the proxy's X-Forwarded-For/-Proto "
    "trusted from this machine only. Needs --server-name.",
)
@click.option(
    "--proxy",
    "proxy",
    metavar="ADDR",
    default=None,
    help="The TLS reverse proxy is at IP address ADDR (another computer): the console serves plain HTTP "
    "to it and to this machine only (every other address refused), its X-Forwarded-* trusted from "
    "ADDR only. Implies --behind-proxy.",
)
@click.option(
    "--server-name",
    "server_names",
    metavar="NAME[:PORT]",
    multiple=True,
    help="A name (or address) the browsers reach the console by, besides 127.0.0.1, localhost, ::1, "
    "--host and the certificate's names; the console answers no other (DNS rebinding). Behind a "
    "proxy: the proxy's name (:PORT when not 443). Repeat for more.",
)
@click.option(
    "--session-idle",
    type=PositiveSeconds(),
    default=None,
    help="End a session after this many seconds without a request from any of its pages [default: 900, 15 min].",
)
@click.option(
    "--session-max",
    type=PositiveSeconds(),
    default=None,
    help="End every session this many seconds after its login [default: 43200, 12 h].",
)
@click.option(
    "--scans-dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Folder the Scan page's scans go into, each a new scan-YYYYmmddTHHMMSSZ folder as `vts scan "
    "start` names it; the motion report and exports go into the scan's folder. A folder of scans "
    "only: one holding anything else (a rig.yaml, a *.env, a store) is refused (exit 2); a new one "
    "is created 0700. [default: scans/ beside the per-user results store, "
    "~/.local/share/vts-hw/scans]",
)
@click.pass_context
def console(
    ctx: click.Context,
    config_path: str | None,
    host: str,
    port: int,
    login: bool,
    certfile: str | None,
    keyfile: str | None,
    behind_proxy: bool,
    proxy: str | None,
    server_names: tuple[str, ...],
    session_idle: float | None,
    session_max: float | None,
    scans_dir: str | None,
) -> None:
    """Serve the room console: a web page of the room's cameras, live.

    The Room page shows every camera's live picture with the markers found on it (named where
    known: wall markers from the drift baseline, the scan's band markers; else numbered), what
    the camera is doing (LIVE, RECORDING, IDLE, NOT ANSWERING), its LED ring with a
    switch, its clock offset and its latest daily QA from the results store. A picture that is
    not live is greyed with its age. The console opens a camera's stream only while a page
    watches it, one stream per camera whatever the number of pages, and never a second one to
    a camera that a recording in the console reads. Open the printed address in a browser
    (Chromium, Firefox); Ctrl-C stops it (exit 0). A port in use or a bad rig.yaml: one
    sentence, exit 2.

    On 127.0.0.1 (the default) the person at this machine may do everything. With --login,
    --behind-proxy or another --host, every page needs a login as one of the users of the
    results store (`vts console user add`); operators run scans, the daily QA and the LEDs,
    acknowledge alerts and push; physicists also set baselines, calibrations and tolerances.
    Every action is logged in the store with who and when (History, "Who did what"), refused
    logins and lock-outs too; a store that is not a vts-hw store, or that this user cannot
    write, is refused in one sentence, exit 3, before a camera is opened (the log is never kept
    only in memory).
    Refused in one sentence, exit 2, before anything starts: another --host in plain HTTP
    (without --certfile/--keyfile, or --proxy ADDR: a login never travels in clear off this
    machine), --behind-proxy without --server-name, 0.0.0.0 with no name to answer to, a login
    asked for with no user in the store, a certificate or key that is not one, a --scans-dir
    that holds anything but scans. The console answers only the names it serves under (others:
    HTTP 400) and takes a POST only from its own pages. docs/operate/console.md, "Console users and
    HTTPS"; docs/security.md.
    """
    if ctx.invoked_subcommand is not None:
        return
    from vts_hw.config import load_rig
    from vts_hw.console.serve_checks import check_host
    from vts_hw.store import ResultsStore

    check_host(
        host, certfile=certfile, keyfile=keyfile, behind_proxy=behind_proxy, proxy=proxy, server_names=server_names
    )
    from vts_hw.console.serve import serve  # the console's pages: loaded once nothing is refused

    rig = load_rig(config_path)
    target = store_target(rig)

    def open_store():
        return ResultsStore(target, mode="read")

    def open_write_store():
        return ResultsStore(target, mode="create")

    serve(
        rig,
        host=host,
        port=port,
        open_store=open_store,
        open_write_store=open_write_store,
        login=login,
        behind_proxy=behind_proxy,
        certfile=certfile,
        keyfile=keyfile,
        session_idle_s=session_idle,
        session_max_s=session_max,
        scans_dir=scans_dir,
        proxy=proxy,
        server_names=server_names,
        on_ready=lambda url: click.echo(f"room console of rig {rig.rig}: open {url} (Ctrl-C stops it)"),
    )
    click.echo("room console stopped")


@console.group()
def user() -> None:
    """The console's users, in the results store (`vts --store`, $VTS_STORE, rig.yaml's store).

    A user has a role: operator (scans, daily QA, LEDs, alerts, push) or physicist (also
    baselines, calibration, tolerances, sign-off). Passwords are kept as salted scrypt hashes,
    never as given.
    """


def _store(config_path, mode):
    from vts_hw.store import ResultsStore

    return ResultsStore(store_target(rig_if_any(config_path)), mode=mode)


@user.command("add")
@config_option
@click.argument("name")
@click.option("--role", type=click.Choice(["operator", "physicist"]), required=True, help="What the user may do.")
@click.option(
    "--password-env",
    metavar="NAME",
    default=None,
    help="Read the password from this environment variable (for scripts); else it is asked for, "
    "twice, without showing it. Never on the command line.",
)
def user_add(config_path: str | None, name: str, role: str, password_env: str | None) -> None:
    """Add user NAME with a role (a disabled one is enabled again with the new password).

    Exit status: 0 added; 2 a bad name, role or password (at least 8 characters), a user
    already there, an unset variable; 3 the store cannot be written.
    """
    from vts_hw.console.users import add_user, check_name

    check_name(name)
    if password_env:
        password = os.environ.get(password_env)
        if not password:
            raise UsageError(f"the environment variable {password_env} (--password-env) is not set")
    else:
        password = ask_password(
            f"password for {name}", "give --password-env NAME, the environment variable that holds it"
        )
    with _store(config_path, "create") as store:
        click.echo(add_user(store, name, role, password))


@user.command("list")
@config_option
@json_option
def user_list(config_path: str | None, as_json: bool) -> None:
    """The users: name, role, and whether they may log in (never a password or its hash).

    Exit status: 0; 3 the store cannot be read (or does not exist yet).
    """
    import datetime as dt

    from vts_hw.console.users import list_users

    with _store(config_path, "read") as store:
        rows, where = list_users(store), store.url
    if as_json:
        echo_json({"store": where, "users": rows})
        return
    if not rows:
        click.echo(f"no console users in {where}")
    for u in rows:
        since = dt.datetime.fromtimestamp(u["changed"], dt.UTC).strftime("%Y-%m-%d")
        state = (
            "may log in"
            if u["active"]
            else "disabled " + dt.datetime.fromtimestamp(u["disabled"], dt.UTC).strftime("%Y-%m-%d")
        )
        click.echo(f"{u['name']:<20} {u['role']:<10} {state} (changed {since})")


@user.command("remove")
@config_option
@click.argument("name")
def user_remove(config_path: str | None, name: str) -> None:
    """Disable user NAME: it can no longer log in, and its sessions end within 10 s. The user is
    kept (disabled), so the actions logged under the name stay that person's; `user add`
    enables it again.

    Exit status: 0; 2 no such user; 3 the store cannot be read or written.
    """
    from vts_hw.console.users import remove_user

    with _store(config_path, "read") as store:
        click.echo(remove_user(store, name))
