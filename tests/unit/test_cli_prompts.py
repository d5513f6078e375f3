"""A command that asks a person (Press Enter when the table has stopped; a password) asks at a
terminal only: without one (a script, a pipe, /dev/null, cron) no one can answer, and that is
one sentence saying what to do instead, exit 2, never an "interrupted" (exit 130) that reads as
if someone pressed Ctrl-C (issue 32 §4). One door for every question: cli/common.py."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from vts_hw.cli import common

REPO = Path(__file__).resolve().parents[2]
ASKS = re.compile(r"\bclick\.(prompt|confirm|getchar)\b|(?<![\w.])input\(|getpass\.")


def test_every_question_goes_through_the_one_door():
    """No module of the package asks a person by itself (the class: a new prompt cannot slip by)."""
    found = []
    for folder in ("vts_hw", "drivers", "procedures", "sim_devices"):
        for path in (REPO / folder).rglob("*.py"):
            if path == REPO / "vts_hw" / "cli" / "common.py":
                continue
            for n, line in enumerate(path.read_text().splitlines(), 1):
                if ASKS.search(line.split("#")[0]):
                    found.append(f"{path.relative_to(REPO)}:{n}: {line.strip()}")
    assert found == []


@pytest.mark.parametrize(
    "ask",
    [
        lambda: common.ask_a_person("Press Enter.", "the step test", "use --analyze DIR"),
        lambda: common.ask_password("password for ann", "give --password-env NAME"),
    ],
    ids=["enter", "password"],
)
def test_without_a_terminal_a_question_is_one_sentence_and_exit_2(ask, monkeypatch):
    monkeypatch.setattr(common, "_terminal", lambda: False)
    with pytest.raises(common.NoTerminal) as got:
        ask()
    assert got.value.exit_code == 2 and "stdin is not" in str(got.value) and "\n" not in str(got.value)
