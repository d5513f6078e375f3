"""`--help` keeps lists as lists (click rewraps every paragraph not marked with ``\\b``), and the
demo's sections are numbered in the order it shows them (issue 21, part A 5)."""

from __future__ import annotations

import inspect
import re

import click
from click.testing import CliRunner

from vts_hw.cli import _register, cli, command_tree

LIST_LINE = re.compile(r"^\s*(\d+[.)]|[-*•])\s+\S")


def test_every_help_paragraph_with_a_list_is_kept_as_written():
    squashed = []
    for path, cmd in command_tree():
        for para in inspect.cleandoc(cmd.help or "").split("\n\n"):
            lines = para.splitlines()
            if sum(bool(LIST_LINE.match(ln)) for ln in lines) >= 2 and not para.startswith("\b"):
                squashed.append(f"vts {' '.join(path)}: {lines[0][:60]!r}")
    assert squashed == []


def test_the_demo_help_shows_its_six_sections_one_per_line():
    _register()
    out = CliRunner().invoke(cli, ["demo", "--help"], terminal_width=100).output
    starts = [ln.strip()[:2] for ln in out.splitlines() if re.match(r"^\s+\d\.\s", ln)]
    assert starts == ["1.", "2.", "3.", "4.", "5.", "6."]


def test_the_demo_numbers_its_sections_in_the_order_shown(monkeypatch, tmp_path):
    """The demo's own printing, its parts replaced by what they say (the whole demo takes minutes:
    `make demo`); the step test and the reports are announced by the messages run_demo sends."""
    from vts_hw.cli import demo as demo_cli
    from vts_hw.sim_devices.scenarios import demo_days

    def fake_run_demo(out, days, frames, on_day, on_step):
        on_step("day 0: baseline set")
        for d in range(1, days + 1):
            on_day(
                demo_days.DayRow(
                    d, 0.0, "OK", {"cam1": {"dx": 0.0, "dy": 0.0, "truth_dx": 0.0, "truth_dy": 0.0, "state": "OK"}}
                )
            )
        on_step(demo_days.STEPS_START)
        on_step("7-sphere step test: OK")
        on_step(demo_days.REPORTS_START)
        return demo_days.DemoResult([], tmp_path / "r.sqlite", tmp_path / "d.html", tmp_path / "d.pdf", {})

    monkeypatch.setattr(demo_days, "run_demo", fake_run_demo)
    monkeypatch.setattr(demo_cli, "_cameras", lambda out, seconds: click.echo("cameras"))
    monkeypatch.setattr(demo_cli, "_scan", lambda out, seconds: click.echo("scan"))
    monkeypatch.setattr(demo_cli, "_patient", lambda out, seconds: click.echo("patient"))
    for extra, n in (([], 6), (["--scan-seconds", "0"], 5), (["--scan-seconds", "0", "--patient-seconds", "0"], 4)):
        r = CliRunner().invoke(cli, ["demo", "-o", str(tmp_path / "d"), "--days", "2", *extra])
        assert r.exit_code == 0, r.output
        heads = re.findall(r"^== (\d+)\. (.*)$", r.output, re.M)
        assert [int(k) for k, _ in heads] == list(range(1, n + 1)), heads
        titles = [t for _, t in heads]
        assert titles[2].startswith("the 7-sphere step test") and titles[3].startswith("the QA reports")
        out = r.output
        assert out.index("2 daily runs") < out.index("== 3.") < out.index("7-sphere step test: OK") < out.index("== 4.")
