"""One catalog of procedures (vts_hw/catalog.py): every reader names procedures through it,
names stored by older versions still read, and a new procedure that is stored, reported and
pushed is its module, one catalog entry and its command — shown with a small one below."""

from __future__ import annotations

import click
import pytest
from click.testing import CliRunner

from vts_hw import catalog
from vts_hw.config import parse_rig
from vts_hw.config_qatrack import QATrackConfig
from vts_hw.results import Measure, overall_state
from vts_hw.store import ResultsStore
from vts_hw.tolerance import DEFAULT_TOLERANCES, State, Window

#: every procedure name runs were stored under before the catalog (they are in stores: they must read)
STORED_BEFORE = ("daily", "drift", "drift-baseline", "sphere-steps", "sync", "spect_mapping", "motion",
                 "calibration", "calibration_cameras")


def test_names_already_stored_still_read_everywhere():
    from vts_hw.report import history, rooms
    from vts_hw.report.drift import BASELINE_PROCEDURE, DRIFT_PROCEDURES
    from vts_hw.report.steps import PROCEDURE as STEPS_NAME
    for name in STORED_BEFORE:
        assert catalog.find(name) is not None, name
    import re
    pattern = catalog.stored_name_pattern()
    assert all(re.match(pattern, n) for n in (*STORED_BEFORE, "qa:reachable+clock"))
    assert not re.match(pattern, "sphere_steps") and not re.match(pattern, "qa:")
    # the readers hold what they held before, now from the catalog
    assert set(DRIFT_PROCEDURES) == {"drift", "daily"} and BASELINE_PROCEDURE == "drift-baseline"
    assert STEPS_NAME == "sphere-steps" and rooms.MAPPING_PROCEDURES == ("spect_mapping",)
    assert set(rooms.CALIBRATION_PROCEDURES) == {"calibration", "calibration_cameras"}
    assert set(catalog.not_room_checks()) == {"motion", "drift-baseline", "commission-step", "commissioning"}
    assert [(s.key, s.procedures, s.room_check) for s in history.specs()] == [
        ("sync", ("sync",), True), ("spect_mapping", ("spect_mapping",), True),
        ("calibration", ("calibration", "calibration_cameras"), True), ("motion", ("motion",), False)]
    assert catalog.label("drift") == catalog.label("daily") == "daily QA"    # one check on the rooms page
    assert catalog.label("qa:clock") == "qa:clock"


def test_an_alias_reads_as_its_procedure(monkeypatch):
    renamed = catalog.Procedure("sphere_steps", "step test", "room", catalog.STEPS.measures,
                                figures=catalog.STEPS.figures, aliases=("sphere-steps",))
    monkeypatch.setattr(catalog, "PROCEDURES", tuple(renamed if p is catalog.STEPS else p for p in catalog.PROCEDURES))
    assert catalog.find("sphere-steps") is renamed and catalog.family("sphere_steps") == ("sphere_steps", "sphere-steps")
    monkeypatch.setattr(catalog, "PROCEDURES", (*catalog.PROCEDURES, renamed))
    with pytest.raises(ValueError, match="twice"):
        catalog.by_name()


def test_the_procedures_measure_what_the_catalog_says():
    """Each procedure's own list of figures, and the tolerance table's units, agree with its entry."""
    from vts_hw.procedures import motion, steps_analysis, sync_verdict
    assert set(steps_analysis.METRICS) == {m for m, _ in catalog.STEPS.measures}
    assert set(sync_verdict.METRICS) == {m for m, _ in catalog.SYNC.measures}
    assert motion.METRICS == dict(catalog.MOTION.measures)
    for p in catalog.PROCEDURES:
        for metric, unit in p.measures:
            w = DEFAULT_TOLERANCES.get(metric)
            assert w is None or w.unit in ("", unit), (p.name, metric)
        assert {f.metric for f in p.figures} <= {m for m, _ in p.measures}, p.name


# ---------------------------------------------------------------- the closing note's demonstration
# A new QA procedure: the LED ring's brightness, LED on against LED off, per camera. What it
# takes: (1) its module — the class below; (2) one catalog entry — LED_CHECK; (3) its command —
# `led` below. Nothing else: the recorder stores it, the drift report's history and the rooms
# page show it, and `vts qa push` maps it, all by reading the catalog.

LED_WINDOW = Window(action_low=0.5, tolerance_low=0.8)


class LedCheck:                                                    # (1) the module
    procedure = "led-check"

    def __init__(self, ratios: dict[str, float]):
        self.ratios = ratios

    @property
    def measures(self):
        return [Measure.judged(cam, "led_level_ratio", r, "", LED_WINDOW) for cam, r in self.ratios.items()]

    @property
    def state(self):
        return overall_state(self.measures)

    def results(self):
        return "\n".join(f"{m.subject}: LED level {m.value:.2f} ({m.state})" for m in self.measures)

    def results_data(self):
        return {"summary": {"state": str(self.state)}, "measures": [m.as_dict() for m in self.measures]}

    def plot(self, path=None):
        return b""


LED_CHECK = catalog.Procedure(                                     # (2) one catalog entry
    "led-check", "LED check", "room", (("led_level_ratio", ""),),
    figures=(catalog.Figure("led_level_ratio", "LED level (worst camera)", ".2f"),), history="LED checks")


@click.command()                                                   # (3) its command
@click.argument("ratios", nargs=-1)
@click.option("--config", "config_path")
def led(ratios, config_path):
    """The LED ring's brightness per camera, CAM=RATIO."""
    from vts_hw.cli.common import finish_analysis, rig_if_any
    rig = rig_if_any(config_path)
    result = LedCheck({c: float(r) for c, r in (x.split("=") for x in ratios)})
    finish_analysis(rig, result, result.results_data(), "LED check", False)


def test_a_new_procedure_is_its_module_one_catalog_entry_and_its_command(monkeypatch, tmp_path):
    import yaml

    from vts_hw.qatrack import push_runs, select_runs
    from vts_hw.report import build_drift_report
    from vts_hw.report.rooms import collect_rooms
    from vts_hw.sim_devices.qatrack_server import QATrackSim

    monkeypatch.setattr(catalog, "PROCEDURES", (*catalog.PROCEDURES, LED_CHECK))
    url = f"sqlite:///{tmp_path / 'results.sqlite'}"
    token = "tok-led-1"
    monkeypatch.setenv("QATRACK_TOKEN", token)
    with QATrackSim({"VTS LED": ["cam1_led", "cam2_led"]}, {"SPECT 1": ["VTS LED"]}, token=token) as peer:
        cfg = {"rig": "room1", "cameras": [{"name": "cam1", "host": "127.0.0.1"}], "store": {"url": url},
               "qatrack": {"url": peer.url, "unit": "SPECT 1", "time_zone": "America/Toronto",
                           "token_env": "QATRACK_TOKEN", "report": "none", "plots": False, "timeout_s": 5.0,
                           "lists": {"led-check": {"test_list": "VTS LED", "macros": {
                               "cam1/led_level_ratio": "cam1_led", "cam2/led_level_ratio": "cam2_led"}}}}}
        (tmp_path / "rig.yaml").write_text(yaml.safe_dump(cfg))
        # stored: the command's exit status is the result's (20 ACTION), its run in the store
        got = CliRunner().invoke(led, ["cam1=0.95", "cam2=0.42", "--config", str(tmp_path / "rig.yaml")])
        assert got.exit_code == 20, got.output
        assert "stored: run" in got.output
        with ResultsStore(url) as store:
            (run,) = store.runs(procedure="led-check")
            assert (run.rig, run.status) == ("room1", "ACTION")
            rows = {m.subject: (m.value, m.status) for m in store.measurements(run_id=run.id)}
            assert rows == {"cam1": (0.95, State.OK), "cam2": (0.42, State.ACTION)}
            # reported: its history section and an "attention" line; the rooms page's open item
            report = build_drift_report(store, tmp_path / "report.html", rig="room1")
            section = [h for h in report.history if h.spec.key == "led-check"]
            assert section and section[0].title == "LED checks" and section[0].latest.values[0] == (0.95, "OK")
            assert any(a.startswith("LED check (room1): ACTION in run") for a in report.attention())
            assert "LED checks" in (tmp_path / "report.html").read_text()
            (room,) = collect_rooms(store).rooms
            assert [(i.check, i.subject) for i in room.open_items] == [("LED check", "cam2")]
            # pushed: the rig's qatrack list is keyed by its stored name; the values reach QATrack+
            qcfg = parse_rig(cfg, "rig.yaml").qatrack
            out = push_runs(store, qcfg, select_runs(store, qcfg, "room1"))
            assert [o.how for o in out] == ["posted"]
        (inst,) = peer.instances
        assert inst["tests"]["cam1_led"]["value"] == pytest.approx(0.95)
        assert inst["tests"]["cam2_led"]["value"] == pytest.approx(0.42)


def test_without_its_catalog_entry_the_new_procedure_cannot_be_mapped():
    """The entry is what makes it known: QATrack+'s mapping refuses a list for a name the
    catalog does not hold (the demonstration's entry is needed, not decoration)."""
    with pytest.raises(ValueError, match="not a procedure stored as runs"):
        QATrackConfig(url="http://127.0.0.1:1/", unit="u", time_zone="UTC", token_env="T",
                      lists={"led-check": {"test_list": "L", "macros": {"cam1/led_level_ratio": "a"}}})
