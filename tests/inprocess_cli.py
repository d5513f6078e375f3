"""`vts ARGS` run in the test's own process (the CLI's main(), as the console script runs it),
for tests that read what it printed with pytest's capsys."""

from __future__ import annotations

from vts_hw.cli import main


def vts(capsys, *args) -> tuple[int, str, str]:
    """`vts ARGS` in this process: (exit code, stdout, stderr)."""
    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as exc:
        code = exc.code or 0
    got = capsys.readouterr()
    return code, got.out, got.err
