"""`vts sync ...`: line the VTS and the SPECT list-mode up in time."""

from __future__ import annotations

from . import cli


@cli.group()
def sync() -> None:
    """Time synchronisation of a scan session with the SPECT list-mode."""
