"""`vts scan ...`: a scan session (trigger + recordings). Filled in by the scan-session work."""

from __future__ import annotations

from . import cli


@cli.group()
def scan() -> None:
    """Start the VTS for a patient scan: cameras recording, trigger fired, live status."""
