"""The checklists of docs/develop/checklists.md, each done by a test with the fewest files
(issue 34 §2): a QA procedure, a trigger backend, a console page, a camera kind.

Each checklist is written here as a patch set: the files it touches (from the checkout's top)
and what goes into each (a new file's whole text, or the lines added to an existing one). The
test applies that patch set to the running package — a new module is imported from tmp_path
under its package name, lines added to a module are run in that module's namespace and every
name they bind or change is set on the module for the test's length — and then shows the new
thing working end to end the way a user meets it. It asserts the patch set's files are the
ones the checklist names in the docs (no file more), and a test per step shows that leaving
that step out breaks it: no file of the patch set is decoration.
"""

from __future__ import annotations

import importlib
import importlib.util
import re
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import click
import cv2
import numpy as np
import pytest
import yaml
from starlette.testclient import TestClient

from inprocess_cli import vts
from vts_hw.cli import COMMANDS, cli
from vts_hw.config import parse_rig
from vts_hw.console.app import Console, create_app
from vts_hw.qatrack import push_runs, select_runs
from vts_hw.report import build_drift_report
from vts_hw.sim_devices.qatrack_server import QATrackSim
from vts_hw.store import ResultsStore
from vts_hw.tolerance import State, Window

ROOT = Path(__file__).resolve().parents[2]
CHECKLISTS = ROOT / "docs" / "develop" / "checklists.md"
#: the checkout's folders installed under another package name (pyproject.toml's package-dir)
PACKAGES = {
    "vts_hw/": "vts_hw.",
    "procedures/": "vts_hw.procedures.",
    "drivers/": "vts_hw.drivers.",
    "sim_devices/": "vts_hw.sim_devices.",
}


@dataclass(frozen=True)
class Change:
    """One file of a checklist's patch set: ``path`` from the checkout's top, ``text`` the new
    file's whole text (``new``) or the lines added at the end of the existing module."""

    path: str
    text: str
    new: bool = False

    @property
    def module(self) -> str:
        for folder, package in PACKAGES.items():
            if self.path.startswith(folder) and self.path.endswith(".py"):
                return package + self.path[len(folder) : -3].replace("/", ".")
        raise AssertionError(f"{self.path}: not a module of the package")


def apply(changes, monkeypatch, tmp_path) -> None:
    """The patch set applied to the running package, undone when the test ends (monkeypatch)."""
    for c in changes:
        assert (ROOT / c.path).exists() != c.new, f"{c.path}: {'already there' if c.new else 'not in the checkout'}"
        if c.new and c.path.startswith(TEMPLATES):
            _template_beside_the_others(c, monkeypatch, tmp_path)
            continue
        if c.new:
            file = tmp_path / c.path
            file.parent.mkdir(parents=True, exist_ok=True)
            file.write_text(textwrap.dedent(c.text))
            spec = importlib.util.spec_from_file_location(c.module, file)
            mod = importlib.util.module_from_spec(spec)
            monkeypatch.setitem(sys.modules, c.module, mod)
            spec.loader.exec_module(mod)
            parent, _, leaf = c.module.rpartition(".")
            monkeypatch.setattr(importlib.import_module(parent), leaf, mod, raising=False)
            continue
        _command_as_vts_loads_it(c.module)
        mod = importlib.import_module(c.module)
        for name, value in list(vars(mod).items()):  # what the lines add to a table or a group is undone
            if name.isupper() and isinstance(value, (dict, list)):
                monkeypatch.setattr(mod, name, type(value)(value))
            elif isinstance(value, click.Group) and getattr(value.callback, "__module__", None) == c.module:
                monkeypatch.setattr(value, "commands", dict(value.commands))
        before = dict(vars(mod))
        ns = dict(before)
        exec(compile(textwrap.dedent(c.text), str(ROOT / c.path), "exec"), ns)
        for name, value in ns.items():
            if name != "__builtins__" and (name not in before or before[name] is not value):
                monkeypatch.setattr(mod, name, value, raising=False)


def _command_as_vts_loads_it(module: str) -> None:
    """A module of vts_hw.cli: its command looked up as `vts` does, every module of it imported
    (`qa` is vts_hw.cli.qa and qa_steps). Imported alone, the group would be registered without
    the others' subcommands, and `vts qa steps` gone for the rest of the process: the lookup
    imports a command's modules only while the command is not registered yet."""
    leaf = module.removeprefix("vts_hw.cli.")
    for name, modules in COMMANDS.items():
        if module.startswith("vts_hw.cli.") and leaf in modules:
            cli.get_command(click.Context(cli), name)


TEMPLATES = "vts_hw/console/templates/"


def _template_beside_the_others(c: Change, monkeypatch, tmp_path) -> None:
    """A new console template: the console's folder seen through tmp_path (its templates and
    static files linked, the new template written beside them), the app's HERE pointing there."""
    from vts_hw.console import app

    here = tmp_path / "console"
    if not here.exists():
        (here / "templates").mkdir(parents=True)
        (here / "static").symlink_to(app.HERE / "static")
        for t in (app.HERE / "templates").iterdir():
            (here / "templates" / t.name).symlink_to(t)
        monkeypatch.setattr(app, "HERE", here)
    (here / "templates" / c.path[len(TEMPLATES) :]).write_text(textwrap.dedent(c.text))


def files_named(section: str) -> list[str]:
    """The files the checklist ``section`` of docs/develop/checklists.md says it touches (its
    "Files:" line), ``<name>`` standing for the new thing's name."""
    text = CHECKLISTS.read_text()
    part = text.split(f"\n## {section}\n", 1)[1].split("\n## ", 1)[0]
    (line,) = [ln for ln in part.splitlines() if ln.startswith("**Files")]
    return re.findall(r"`([^`]+)`", line)


def assert_files(changes, section: str) -> None:
    """The patch set touches exactly the files the checklist names, and no more."""
    named = files_named(section)
    touched = [c.path for c in changes]
    assert len(touched) == len(set(touched)) == len(named), (touched, named)
    for path, pattern in zip(touched, named):
        assert re.fullmatch(re.escape(pattern).replace("<name>", r"[a-z_]+"), path), (path, pattern)


# ================================================================ a QA procedure
# The LED ring's brightness per camera (the wall markers' level with the LED on over LED off):
# its module, one catalog entry, its command. Nothing else: the recorder stores it with its
# window, rig.yaml's tolerances: take its metric, the drift report's history, the rooms page,
# the console's history and QATrack+'s push show it, and `vts qa --help` and the command
# reference list it, all by reading the catalog and the command tree.

LED_MODULE = Change(
    "procedures/led_check.py",
    new=True,
    text='''
    """The LED ring's brightness per camera: the wall markers' level with the LED on over their
    level with it off (the toy QA procedure of tests/house/test_checklists.py)."""

    from __future__ import annotations

    from vts_hw import catalog
    from vts_hw.results import Measure, overall_state

    METRIC = "led_level_ratio"


    class LedCheck:
        procedure = "led-check"

        def __init__(self, ratios: dict[str, float]):
            self.ratios = dict(ratios)
            self.windows = catalog.windows()

        def analyze(self, tolerances=None) -> "LedCheck":
            self.windows = catalog.windows(tolerances)      # the rig's windows on the catalog's
            return self

        @property
        def measures(self) -> list[Measure]:
            return [Measure.judged(cam, METRIC, r, "", self.windows[METRIC]) for cam, r in sorted(self.ratios.items())]

        @property
        def state(self):
            return overall_state(self.measures)

        def results(self) -> str:
            return "\\n".join(f"{m.subject}: LED level {m.value:.2f} ({m.state})" for m in self.measures)

        def results_data(self) -> dict:
            return {"summary": {"state": str(self.state)}, "measures": [m.as_dict() for m in self.measures]}

        def plot(self, path=None):
            return None
''',
)

LED_ENTRY = Change(
    "vts_hw/catalog.py",
    text="""
    LED_CHECK = Procedure("led-check", "LED check", "room", (("led_level_ratio", ""),),
                          figures=(Figure("led_level_ratio", "LED level, largest of the cameras", ".2f"),),
                          history="LED checks", windows=(("led_level_ratio", Window(action_low=0.5, tolerance_low=0.8)),))
    PROCEDURES = (*PROCEDURES, LED_CHECK)
""",
)

LED_COMMAND = Change(
    "vts_hw/cli/qa.py",
    text='''
    from vts_hw.cli.common import config_option, finish_analysis, rig_if_any
    from vts_hw.procedures.led_check import LedCheck


    @qa.command("led")
    @click.argument("ratios", nargs=-1, required=True, metavar="CAMERA=RATIO...")
    @config_option
    @json_option
    def led(ratios, config_path, as_json) -> None:
        """The LED ring's brightness per camera: the markers' level with the LED on over off."""
        rig = rig_if_any(config_path)
        try:
            levels = {cam: float(r) for cam, _, r in (x.partition("=") for x in ratios)}
        except ValueError:
            raise click.BadParameter("each is CAMERA=RATIO, the ratio a number", param_hint="RATIOS") from None
        result = LedCheck(levels).analyze(rig.tolerances if rig is not None else None)
        finish_analysis(rig, result, result.results_data(), "LED check", as_json)
''',
)

QA_PROCEDURE = (LED_MODULE, LED_ENTRY, LED_COMMAND)
LED_TOKEN = "tok-led-1"


def _docs_site():
    spec = importlib.util.spec_from_file_location("docs_site", ROOT / "tools" / "docs_site.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _led_rig(tmp_path, peer_url: str = "http://127.0.0.1:9/") -> tuple[Path, dict]:
    cfg = {
        "rig": "room1",
        "cameras": [{"name": "cam1", "host": "127.0.0.1"}, {"name": "cam2", "host": "127.0.0.1"}],
        "store": {"url": f"sqlite:///{tmp_path / 'results.sqlite'}"},
        # the rig's own window for the new metric: cam1's 0.85 is OK by the catalog's, TOLERANCE by this
        "tolerances": {"led_level_ratio": {"action_low": 0.4, "tolerance_low": 0.9}},
        "qatrack": {
            "url": peer_url,
            "unit": "SPECT 1",
            "time_zone": "America/Toronto",
            "token_env": "QATRACK_TOKEN",
            "report": "none",
            "plots": False,
            "timeout_s": 5.0,
            "lists": {
                "led-check": {
                    "test_list": "VTS LED",
                    "macros": {"cam1/led_level_ratio": "cam1_led", "cam2/led_level_ratio": "cam2_led"},
                }
            },
        },
    }
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path, cfg


def test_the_qa_procedure_checklist_names_its_three_files():
    assert_files(QA_PROCEDURE, "A QA procedure")
    assert len({Path(c.path).parts[0] for c in QA_PROCEDURE}) == 2  # procedures/ and vts_hw/


def test_a_qa_procedure_is_its_module_one_catalog_entry_and_its_command(monkeypatch, tmp_path, capsys):
    apply(QA_PROCEDURE, monkeypatch, tmp_path)
    monkeypatch.setenv("QATRACK_TOKEN", LED_TOKEN)
    monkeypatch.delenv("VTS_STORE", raising=False)
    with QATrackSim({"VTS LED": ["cam1_led", "cam2_led"]}, {"SPECT 1": ["VTS LED"]}, token=LED_TOKEN) as peer:
        rig_yaml, cfg = _led_rig(tmp_path, peer.url)
        # listed: `vts qa --help` and the command reference the docs site generates
        code, out, _ = vts(capsys, "qa", "--help")
        assert code == 0 and re.search(r"^\s+led\s+The LED ring's brightness", out, re.M), out
        assert "\n### vts qa led\n" in _docs_site().commands_page()
        assert "| `led_level_ratio` | 0.5 | 0.8 |" in _docs_site().rig_yaml_page()
        # stored: the command exits by the result's state (20 ACTION), judged by the catalog's window ...
        plain = tmp_path / "plain.yaml"
        plain.write_text(yaml.safe_dump({k: v for k, v in cfg.items() if k != "tolerances"}))
        code, out, err = vts(capsys, "qa", "led", "cam1=0.85", "cam2=0.3", "--config", plain)
        assert code == 20 and "cam1: LED level 0.85 (OK)" in out and "stored: run" in out, (out, err)
        with ResultsStore(cfg["store"]["url"]) as store:
            (first,) = store.runs(procedure="led-check")
            ms = store.measurements(run_id=first.id)
            assert set(store.windows(m.tolerance_id for m in ms).values()) == {
                Window(action_low=0.5, tolerance_low=0.8)
            }
        # ... and by the rig's own window for it
        code, out, err = vts(capsys, "qa", "led", "cam1=0.85", "cam2=0.3", "--config", rig_yaml)
        assert code == 20, (out, err)
        assert "cam1: LED level 0.85 (TOLERANCE)" in out and "stored: run" in out
        with ResultsStore(cfg["store"]["url"]) as store:
            (_, run) = store.runs(procedure="led-check")
            assert (run.rig, run.status) == ("room1", "ACTION")
            ms = store.measurements(run_id=run.id)
            assert {m.subject: (m.value, m.status) for m in ms} == {
                "cam1": (0.85, State.TOLERANCE),
                "cam2": (0.3, State.ACTION),
            }
            # ... with the window that judged it, as every metric's
            windows = store.windows(m.tolerance_id for m in ms)
            assert set(windows.values()) == {Window(action_low=0.4, tolerance_low=0.9)}
            # reported: its history section (with its window) and an "attention" line
            report = build_drift_report(store, tmp_path / "report.html", rig="room1")
            (section,) = [h for h in report.history if h.spec.key == "led-check"]
            assert section.title == "LED checks" and section.latest.values[0] == (0.85, "TOLERANCE")
            assert section.window_now == Window(action_low=0.4, tolerance_low=0.9)
            assert any(a.startswith("LED check (room1): ACTION in run") for a in report.attention())
            # pushed: the rig's qatrack list is keyed by its stored name; the values reach QATrack+
            qcfg = parse_rig(cfg, "rig.yaml").qatrack
            assert [o.how for o in push_runs(store, qcfg, select_runs(store, qcfg, "room1"))] == ["posted", "posted"]
        assert [inst["tests"]["cam2_led"]["value"] for inst in peer.instances] == [pytest.approx(0.3)] * 2
    # listed in the console: its history page by its label, the run's page, the rooms page
    console = Console("room1", None, None, None, open_store=lambda: ResultsStore(cfg["store"]["url"], mode="read"))
    with TestClient(create_app(console), base_url="http://127.0.0.1:8040") as client:
        page = client.get("/history", params={"procedure": "LED check"})
        assert page.status_code == 200 and f'<tr data-run="{run.id}"' in page.text
        assert '<option value="LED check" selected>' in page.text, re.findall(r"<option[^>]*>[^<]*", page.text)
        one = client.get(f"/history/run/{run.id}")
        assert one.status_code == 200 and "LED check" in one.text and "led_level_ratio" in one.text
        rooms = client.get("/history/rooms/")
        (link,) = set(re.findall(r'href="(rooms-[^"]+\.html)"', rooms.text))
        room = client.get(f"/history/rooms/{link}").text
        assert re.search(r"LED check.{0,400}cam2", room, re.S), room[:3000]


def test_a_qa_procedure_without_its_module_cannot_be_commanded(monkeypatch, tmp_path):
    with pytest.raises(ModuleNotFoundError, match="vts_hw.procedures.led_check"):
        apply((LED_ENTRY, LED_COMMAND), monkeypatch, tmp_path)


def test_a_qa_procedure_without_its_catalog_entry_is_refused_by_rig_yaml(monkeypatch, tmp_path, capsys):
    apply((LED_MODULE, LED_COMMAND), monkeypatch, tmp_path)
    rig_yaml, _ = _led_rig(tmp_path)
    code, out, err = vts(capsys, "qa", "led", "cam1=0.85", "--config", rig_yaml)
    assert code == 2 and "'led_level_ratio', which is not a metric with a tolerance window" in err, err
    assert not (tmp_path / "results.sqlite").exists()


def test_a_qa_procedure_without_its_command_is_not_in_vts(monkeypatch, tmp_path, capsys):
    apply((LED_MODULE, LED_ENTRY), monkeypatch, tmp_path)
    rig_yaml, _ = _led_rig(tmp_path)
    code, out, err = vts(capsys, "qa", "led", "cam1=0.85", "--config", rig_yaml)
    assert code == 2 and "No such command 'led'" in err, err


# ================================================================ a trigger backend
# A trigger generator in memory, with one key of its own: its module and one registry line.

TOY_TRIGGER = Change(
    "drivers/toy_trigger.py",
    new=True,
    text='''
    """A trigger generator in memory (the toy backend of tests/house/test_checklists.py): what it
    starts and stops, it writes to the trigger log as neutral rows."""

    from __future__ import annotations

    from pydantic import Field

    from vts_hw.drivers.trigger import DUTY, FREQUENCY, BackendSettings, TriggerBackend, TriggerBase, TriggerStatus
    from vts_hw.recording.trigger_log import HOST_WRITE


    class Settings(BackendSettings):
        flavour: str = Field(default="plain", pattern=r"^[a-z]+$")


    class ToyTrigger(TriggerBase):
        capabilities = frozenset({FREQUENCY, DUTY})

        def __init__(self, address: str, flavour: str, log):
            super().__init__("toy", log)
            self.address, self.flavour, self.wave, self.running = address, flavour, None, False

        def configure(self, frequency_hz, duty=0.5, high_v=None, low_v=None):
            self.wave = (frequency_hz, duty)
            return self.status()

        def start(self):
            self.running = True
            f, d = self.wave
            self.log.wave_started(self.name, self.log.clock(), period_s=1 / f, duty=d, high_v=5.0, low_v=0.0,
                                  start_pulse=False, time_source=HOST_WRITE, uncertainty_s=0.0)
            return self.status()

        def stop(self):
            if self.running:
                self.log.wave_stopped(self.name, self.log.clock(), rising_edges=None, time_source=HOST_WRITE,
                                      uncertainty_s=0.0)
            self.running = False
            return self.status()

        def status(self):
            f, d = self.wave or (None, None)
            return TriggerStatus("toy", self.running, f, d, notes=(f"a {self.flavour} toy at {self.address}",))


    BACKEND = TriggerBackend("toy", "a toy in memory", Settings,
                             lambda cfg, settings, log: ToyTrigger(cfg.address, settings.flavour, log))
''',
)

TOY_TRIGGER_LINE = Change(
    "drivers/registry.py",
    text="""
    TRIGGER_BACKENDS["toy"] = "vts_hw.drivers.toy_trigger:BACKEND"
""",
)

TRIGGER_BACKEND = (TOY_TRIGGER, TOY_TRIGGER_LINE)


def _trigger_rig(tmp_path, **keys) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "rig": "t",
                "cameras": [{"name": "cam1", "host": "127.0.0.1"}],
                "trigger": {"backend": "toy", "address": "mem://1", "frequency_hz": 2.0, "duty": 0.25, **keys},
            }
        )
    )
    return path


def test_the_trigger_backend_checklist_names_its_two_files():
    assert_files(TRIGGER_BACKEND, "A trigger backend")


def test_a_trigger_backend_is_its_module_and_one_registry_line(monkeypatch, tmp_path, capsys):
    from vts_hw.drivers.trigger import read_log

    apply(TRIGGER_BACKEND, monkeypatch, tmp_path)
    rig_yaml = _trigger_rig(tmp_path, flavour="sour")
    code, out, err = vts(capsys, "trigger", "start", "--config", rig_yaml, "--log", tmp_path / "trigger.csv")
    assert code == 0, err
    assert out.splitlines() == ["toy: output ON, 2 Hz, duty 25 %", "  a sour toy at mem://1"]
    assert [r["kind"] for r in read_log(tmp_path / "trigger.csv")] == ["wave_start"]
    code, out, err = vts(capsys, "trigger", "stop", "--config", rig_yaml, "--log", tmp_path / "trigger.csv")
    assert code == 0 and out.startswith("toy: output OFF"), err
    # its own keys: checked by its model, one sentence naming the file and the key; listed in the reference
    bad = _trigger_rig(tmp_path, flavor="sour")
    code, out, err = vts(capsys, "trigger", "status", "--config", bad, "--log", tmp_path / "t2.csv")
    assert (code, err.strip()) == (2, f"vts: {bad}: trigger.flavor is not a known key"), err
    page = _docs_site().rig_yaml_page()
    assert "a toy in memory" in page and "`trigger.flavour`" in page


def test_a_trigger_backend_without_its_module_is_not_opened(monkeypatch, tmp_path):
    from vts_hw.drivers import registry

    apply((TOY_TRIGGER_LINE,), monkeypatch, tmp_path)
    with pytest.raises(ModuleNotFoundError, match="vts_hw.drivers.toy_trigger"):
        registry.open_trigger(parse_rig(yaml.safe_load(_trigger_rig(tmp_path).read_text()), "rig.yaml"))


def test_a_trigger_backend_without_its_registry_line_is_refused(monkeypatch, tmp_path, capsys):
    apply((TOY_TRIGGER,), monkeypatch, tmp_path)
    rig_yaml = _trigger_rig(tmp_path)
    code, out, err = vts(capsys, "trigger", "status", "--config", rig_yaml, "--log", tmp_path / "t.csv")
    assert code == 2 and "trigger.backend 'toy' is not a trigger backend" in err, err


# ================================================================ a console page
# The procedures the catalog holds, as a page: its module, its template and one line in PAGES.

TOY_PAGE = Change(
    "vts_hw/console/procedures_page.py",
    new=True,
    text='''
    """The Procedures page: every QA procedure the catalog holds, what it judges and measures
    (the toy console page of tests/house/test_checklists.py)."""

    from __future__ import annotations

    from starlette.requests import Request
    from starlette.routing import Route

    from vts_hw import catalog


    def procedures_routes(console, templates) -> list[Route]:
        async def page(request: Request):
            return templates.TemplateResponse(request, "procedures.html", {
                "rig": console.rig_name, "here": "procedures", "procedures": catalog.PROCEDURES})
        return [Route("/procedures", page)]
''',
)

TOY_TEMPLATE = Change(
    "vts_hw/console/templates/procedures.html",
    new=True,
    text="""
    {% extends "page.html" %}
    {% block title %}Procedures{% endblock %}
    {% block content %}
    <table class="procedures">
      <thead><tr><th>Procedure</th><th>Stored as</th><th>Judges</th><th>Measures</th></tr></thead>
      <tbody>
      {% for p in procedures %}
        <tr data-procedure="{{ p.name }}"><td>{{ p.label }}</td><td>{{ p.name }}</td><td>{{ p.judges }}</td>
          <td>{{ p.measures|map('first')|join(', ') }}</td></tr>
      {% endfor %}
      </tbody>
    </table>
    {% endblock %}
""",
)

TOY_PAGE_LINE = Change(
    "vts_hw/console/app.py",
    text="""
    from vts_hw.console.procedures_page import procedures_routes
    PAGES = [*PAGES, Page(procedures_routes, "procedures", "Procedures", "/procedures")]
""",
)

CONSOLE_PAGE = (TOY_PAGE, TOY_TEMPLATE, TOY_PAGE_LINE)


def _console_client(store_url: str | None = None) -> TestClient:
    from vts_hw.console import app

    console = app.Console(
        "room1",
        SimpleNamespace(names=[]),
        None,
        None,  # a room without cameras
        open_store=(lambda: ResultsStore(store_url, mode="read")) if store_url else None,
    )
    return TestClient(app.create_app(console), base_url="http://127.0.0.1:8040")


def test_the_console_page_checklist_names_its_three_files():
    assert_files(CONSOLE_PAGE, "A console page")


def test_a_console_page_is_its_module_its_template_and_one_line(monkeypatch, tmp_path):
    apply(CONSOLE_PAGE, monkeypatch, tmp_path)
    with _console_client(f"sqlite:///{tmp_path / 'results.sqlite'}") as client:
        page = client.get("/procedures")
        assert page.status_code == 200, page.text
        assert '<tr data-procedure="sphere-steps"><td>step test</td>' in page.text
        assert '<a href="/procedures" class="here">Procedures</a>' in page.text
        # linked from every other page's nav bar, the Room page's included
        for other in ("/", "/history", "/qa", "/scan"):
            assert '<a href="/procedures">Procedures</a>' in client.get(other).text, other
        assert '<a href="/" class="here">Room</a>' in client.get("/").text
        # behind the console's gates: a Host name it does not serve is refused, the headers are set
        assert client.get("/procedures", headers={"Host": "evil.example"}).status_code == 400
        assert page.headers["X-Content-Type-Options"] == "nosniff"


def test_a_console_page_without_its_module_cannot_be_registered(monkeypatch, tmp_path):
    with pytest.raises(ModuleNotFoundError, match="vts_hw.console.procedures_page"):
        apply((TOY_TEMPLATE, TOY_PAGE_LINE), monkeypatch, tmp_path)


def test_a_console_page_without_its_template_is_no_page(monkeypatch, tmp_path):
    apply((TOY_PAGE, TOY_PAGE_LINE), monkeypatch, tmp_path)
    with _console_client() as client:
        got = client.get("/procedures")
    assert got.status_code == 500 and "Procedures" not in got.text


def test_a_console_page_without_its_line_is_neither_served_nor_linked(monkeypatch, tmp_path):
    apply((TOY_PAGE, TOY_TEMPLATE), monkeypatch, tmp_path)
    with _console_client() as client:
        assert client.get("/procedures").status_code == 404
        assert "/procedures" not in client.get("/history").text


# ================================================================ a camera kind
# A camera that makes its own pictures (a grey field, its level an option of its own): frames,
# device information and a clock, the roles every camera has, and no LED or parameters.

TOY_CAMERA = Change(
    "drivers/pattern.py",
    new=True,
    text='''
    """A camera that makes its own pictures: a grey field of one level (the toy camera kind of
    tests/house/test_checklists.py). No LED, no parameters: it has the roles every camera has."""

    from __future__ import annotations

    import threading
    import time

    import cv2
    import numpy as np
    from pydantic import BaseModel, ConfigDict, Field

    from vts_hw.camera import ClockOffset, Frame, kind_settings
    from vts_hw.camera_stream import FrameStream


    class PatternOptions(BaseModel):
        model_config = ConfigDict(extra="forbid")
        level: int = Field(default=128, ge=0, le=255, description="the grey level of every picture")


    PatternSettings = kind_settings("PatternSettings", "A camera that makes its own grey pictures; no address.",
                                    ("resolution", "fps"), options=PatternOptions)


    class PatternCamera:
        settings = PatternSettings

        def __init__(self, name: str, level: int, resolution: str, fps: float, clock=time.time):
            self.name, self.level, self.resolution, self.fps, self.clock = name, level, resolution, fps, clock
            self.seq = 0

        @classmethod
        def from_config(cls, cfg, clock=time.time) -> "PatternCamera":
            s = cls.settings.from_entry(cfg)
            return cls(cfg.name, s.level, cfg.resolution_str, cfg.fps, clock=clock)

        def _frame(self, seq: int) -> Frame:
            w, h = (int(x) for x in self.resolution.split("x"))
            ok, jpeg = cv2.imencode(".jpg", np.full((h, w), self.level, np.uint8))
            return Frame(seq, jpeg.tobytes(), None, self.clock(), time_source="receipt")

        def snapshot(self, compression: int | None = None) -> Frame:
            self.seq += 1
            return self._frame(self.seq)

        def open_stream(self, *, fps=None, duration=None, nbrofframes=None, first_seq=0, stall_timeout=2.0):
            return _Pictures(self, first_seq, nbrofframes, 1 / (fps or self.fps))

        def stream(self, **kwargs) -> FrameStream:
            return FrameStream(self, **kwargs)

        def device_info(self) -> dict[str, str]:
            return {"Brand": "vts-hw", "ProdNbr": "pattern", "Level": str(self.level)}

        def clock_offset(self, samples: int = 5) -> ClockOffset:
            return ClockOffset(0.0, 0.0, self.clock(), "receipt (no camera clock)", 0, source="receipt")

        def close(self) -> None:
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.close()


    class _Pictures:
        def __init__(self, cam: PatternCamera, seq: int, left: int | None, period: float):
            self.cam, self.seq, self.left, self.period = cam, seq, left, period
            self._closed = threading.Event()

        def close(self) -> None:
            self._closed.set()

        def __iter__(self):
            while not self._closed.wait(self.period) and self.left != 0:
                yield self.cam._frame(self.seq)
                self.seq += 1
                self.left = None if self.left is None else self.left - 1
''',
)

TOY_CAMERA_LINE = Change(
    "drivers/registry.py",
    text="""
    CAMERA_KINDS["pattern"] = "vts_hw.drivers.pattern:PatternCamera"
""",
)

CAMERA_KIND = (TOY_CAMERA, TOY_CAMERA_LINE)


def _camera_rig(tmp_path, **options) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(
        yaml.safe_dump(
            {"rig": "t", "cameras": [{"name": "cam1", "kind": "pattern", "resolution": [64, 48], "options": options}]}
        )
    )
    return path


def test_the_camera_kind_checklist_names_its_two_files():
    assert_files(CAMERA_KIND, "A camera kind")


def test_a_camera_kind_is_its_module_and_one_registry_line(monkeypatch, tmp_path, capsys):
    from vts_hw.camera import Camera, roles_of
    from vts_hw.drivers.registry import open_cameras

    apply(CAMERA_KIND, monkeypatch, tmp_path)
    rig_yaml = _camera_rig(tmp_path, level=200)
    (cam,) = open_cameras(parse_rig(yaml.safe_load(rig_yaml.read_text()), "rig.yaml").cameras)
    with cam:
        assert isinstance(cam, Camera) and roles_of(cam) == ("frames", "device information", "clock")
        frames = list(cam.stream(nbrofframes=2, fps=50))
        assert [f.seq for f in frames] == [0, 1] and frames[0].time_source == "receipt"
    # the commands of any camera: a snapshot (the JPEG as it made it), its information
    code, out, err = vts(capsys, "camera", "snapshot", "cam1", "-o", tmp_path / "a.jpg", "--config", rig_yaml)
    assert code == 0, err
    img = cv2.imdecode(np.frombuffer((tmp_path / "a.jpg").read_bytes(), np.uint8), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (48, 64) and abs(int(np.median(img)) - 200) <= 2
    code, out, err = vts(capsys, "camera", "info", "cam1", "--config", rig_yaml)
    assert code == 0 and "  ProdNbr: pattern" in out and "no camera clock" in out, err
    # its own key checked by its own model: one sentence naming the camera, the kind and the key
    code, out, err = vts(capsys, "camera", "info", "cam1", "--config", _camera_rig(tmp_path, level=300))
    assert (
        code == 2
        and err.startswith("vts: camera 'cam1' (kind pattern): options.level: ")
        and len(err.strip().splitlines()) == 1
    ), err
    # listed with its keys in the rig.yaml reference, from its settings model
    page = _docs_site().rig_yaml_page()
    assert "### `kind: pattern`" in page and "`cameras[].options.level`" in page and "`cameras[].fps`" in page


def test_a_camera_kind_without_its_module_is_not_opened(monkeypatch, tmp_path):
    from vts_hw.drivers.registry import open_cameras

    apply((TOY_CAMERA_LINE,), monkeypatch, tmp_path)
    with pytest.raises(ModuleNotFoundError, match="vts_hw.drivers.pattern"):
        open_cameras(parse_rig(yaml.safe_load(_camera_rig(tmp_path).read_text()), "rig.yaml").cameras)


def test_a_camera_kind_without_its_registry_line_is_refused(monkeypatch, tmp_path, capsys):
    apply((TOY_CAMERA,), monkeypatch, tmp_path)
    code, out, err = vts(capsys, "camera", "info", "cam1", "--config", _camera_rig(tmp_path))
    assert code == 2 and "camera 'cam1': unknown kind 'pattern'" in err, err
