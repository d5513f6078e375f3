"""Which store a command uses: ``--store URL`` > ``$VTS_STORE`` > rig.yaml's ``store:`` > the
per-user SQLite file (see docs/decisions/0038-postgresql-store.md).

A password never rides in a URL given on the command line, in the environment or in rig.yaml
(command lines show in ``ps`` and shell histories, files get copied): such a URL is refused
with one sentence. The password comes from the environment variable the config names
(``store.password_env``; ``--store-password-env`` / ``$VTS_STORE_PASSWORD_ENV`` with a URL
given on the command line or in $VTS_STORE), else from libpq's own PGPASSWORD or ~/.pgpass.
"""

from __future__ import annotations

import os
import re

from sqlalchemy.exc import ArgumentError

from vts_hw.errors import UsageError
from vts_hw.store.paths import StoreTarget, to_url

ENV_STORE = "VTS_STORE"
ENV_STORE_PASSWORD_ENV = "VTS_STORE_PASSWORD_ENV"
_ENV_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def checked(
    url: str | None, password_env: str | None, source: str, password_option: str = "--store-password-env"
) -> StoreTarget:
    """A StoreTarget for a URL given by a user (``source`` names where: "--store", ...);
    UsageError (exit 2) for a URL that does not parse, holds a password, or a bad variable name."""
    if url is not None and "://" in url:
        try:
            parsed = to_url(url)
        except ArgumentError:
            raise UsageError(
                f"{source}: {url!r} is not a database URL (expected e.g. "
                "sqlite:////path/results.sqlite or postgresql://user@host/db)"
            ) from None
        if parsed.password is not None:
            raise UsageError(
                f"{source}: the database URL holds a password; remove it and put the password "
                f"in an environment variable named by {password_option}"
            )
    if password_env is not None and not _ENV_NAME.match(password_env):
        raise UsageError(f"{source}: {password_env!r} is not an environment variable name")
    return StoreTarget(url=url or None, password_env=password_env or None, source=source)


def resolve_target(cli_url: str | None = None, cli_password_env: str | None = None, rig=None) -> StoreTarget:
    """The store to use: the command line's URL, else $VTS_STORE, else the rig config's
    ``store:`` section, else the per-user default. The password variable goes with the URL's
    source (the command line's or $VTS_STORE_PASSWORD_ENV for the first two)."""
    env_pw = os.environ.get(ENV_STORE_PASSWORD_ENV) or None
    if cli_url:
        return checked(cli_url, cli_password_env or env_pw, "--store")
    env_url = os.environ.get(ENV_STORE)
    if env_url:
        return checked(env_url, cli_password_env or env_pw, f"${ENV_STORE}")
    section = getattr(rig, "store", None)
    if section is not None and section.url:
        return StoreTarget(
            url=section.url, password_env=cli_password_env or section.password_env, source="rig.yaml store.url"
        )
    return StoreTarget(url=None, password_env=None, source="default")
