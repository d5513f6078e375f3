"""The neutral rows of trigger.csv (docs/trigger-log-format.md) and the trigger backend registry.

The sync analysis and the simulated SPECT read a trigger log through one reader that looks at
the neutral rows only; a log written before them is converted on read. A new backend is one
module and one line in ``TRIGGER_BACKENDS``: here one defined in this test module, opened from
a rig.yaml, planned, checked, fired and stopped by the scan's trigger code, and read back.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import yaml
from pydantic import Field

from vts_hw.config import load_rig
from vts_hw.drivers import registry
from vts_hw.drivers.trigger import (
    DUTY,
    FIRE,
    FREQUENCY,
    LEVELS,
    BackendSettings,
    TriggerBackend,
    TriggerBase,
    TriggerStatus,
    read_log,
)
from vts_hw.errors import ConfigError, DataError
from vts_hw.procedures.scan import ScanSession
from vts_hw.procedures.scan_trigger import ScanError, ScanTrigger
from vts_hw.recording.trigger_log import HOST_WRITE, parse_fields, wave_start_text, wave_stop_text
from vts_hw.recording.trigger_wave import square_wave_edges, wave_from_trigger_log

HEADER = "host_time,device_time_us,device,kind,text\n"
T0 = 1_795_000_000.0
VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


def write_log(path, rows):
    path.write_text(
        HEADER + "".join(f'{T0 + h!r},{dev_us},{dev},{kind},"{text}"\n' for h, dev_us, dev, kind, text in rows)
    )
    return path


# ---- the rows -------------------------------------------------------------------------------------


def test_a_row_says_what_was_started_and_how_its_time_is_known():
    text = wave_start_text(
        period_s=0.5,
        duty=0.25,
        high_v=2.5,
        low_v=0.0,
        start_pulse=True,
        time_source=HOST_WRITE,
        uncertainty_s=0.00123456,
    )
    assert text == "period_s=0.5 duty=0.25 high_v=2.5 low_v=0.0 start_pulse=yes time=host_write uncertainty_s=0.00123"
    assert parse_fields(text)["period_s"] == "0.5"
    assert wave_stop_text(rising_edges=None, time_source=HOST_WRITE, uncertainty_s=None) == "time=host_write"
    with pytest.raises(ValueError, match="time must be one of"):
        wave_stop_text(rising_edges=3, time_source="guessed", uncertainty_s=None)
    with pytest.raises(ValueError, match="not a square wave"):
        wave_start_text(
            period_s=0.0, duty=0.5, high_v=5, low_v=0, start_pulse=False, time_source=HOST_WRITE, uncertainty_s=None
        )


def test_the_reader_reads_the_neutral_rows_only(tmp_path):
    """A backend nobody knows ("toy") and wire text that says something else: the neutral rows
    decide (the *TRG and OUTP OFF lines here would put the start at 1.0 s and a 2 Hz wave)."""
    p = write_log(
        tmp_path / "trigger.csv",
        [
            (0.0, "", "toy", "cmd", "FREQ 2"),
            (1.0, "", "toy", "cmd", "*TRG"),
            (
                1.5,
                "777",
                "toy",
                "wave_start",
                "period_s=0.25 duty=0.5 high_v=3.3 low_v=0.0 start_pulse=yes "
                "time=device_clock_mapped uncertainty_s=0.0002",
            ),
            (3.0, "", "toy", "cmd", "OUTP OFF"),
            (4.0, "", "toy", "wave_stop", "rising_edges=10 time=device_clock_mapped uncertainty_s=0.0002"),
            (
                5.0,
                "",
                "toy",
                "clock",
                "drift_ppm=12.0 drift_se_ppm=0.5 residual_s=4e-05 uncertainty_s=9e-05 samples=20",
            ),
        ],
    )
    w = wave_from_trigger_log(p)
    assert (w.device, w.start_host, w.period_s, w.duty, w.high_v, w.low_v) == ("toy", T0 + 1.5, 0.25, 0.5, 3.3, 0.0)
    assert (w.n_rising, w.stop_host, w.start_pulse, w.converted) == (10, T0 + 1.5 + 2.5, True, False)
    assert (w.time_source, w.uncertainty_s, w.drift_ppm) == ("device_clock_mapped", 0.0002, 12.0)
    assert w.host_period_s == pytest.approx(0.25 * (1 + 12e-6), rel=1e-12)
    rising, falling = square_wave_edges(w)
    assert rising.size == 10 and np.allclose(falling - rising, 0.125)
    with pytest.raises(DataError, match="no square wave was started in this trigger log by 'other'"):
        wave_from_trigger_log(p, "other")


def test_a_wave_cut_at_its_stop_and_the_last_of_several(tmp_path):
    """Two waves of a device that stops at once (no edge count): the last one, cut at its stop."""
    start = "period_s=1.0 duty=0.5 high_v=5.0 low_v=0.0 start_pulse=no time=host_write uncertainty_s=0.001"
    p = write_log(
        tmp_path / "trigger.csv",
        [
            (0.0, "", "daqmx", "wave_start", start),
            (3.0, "", "daqmx", "wave_stop", "time=host_write"),
            (10.0, "", "daqmx", "wave_start", start),
            (12.7, "", "daqmx", "wave_stop", "time=host_write"),
        ],
    )
    w = wave_from_trigger_log(p)
    assert (w.start_host, w.stop_host, w.n_rising) == (T0 + 10.0, T0 + 12.7, None)
    rising, falling = square_wave_edges(w)
    assert np.allclose(rising - T0, [10, 11, 12]) and np.allclose(falling - T0, [10.5, 11.5, 12.5])
    p = write_log(tmp_path / "open.csv", [(0.0, "", "daqmx", "wave_start", start)])
    assert wave_from_trigger_log(p).stop_host is None
    with pytest.raises(ValueError, match="never stopped"):
        square_wave_edges(wave_from_trigger_log(p))
    bad = write_log(tmp_path / "bad.csv", [(0.0, "", "daqmx", "wave_start", "duty=0.5 time=host_write")])
    with pytest.raises(DataError, match="bad.csv: the wave_start row of daqmx .* lacks period_s"):
        wave_from_trigger_log(bad)


@pytest.mark.parametrize(
    "start, stop, why",
    [
        ("period_s=2.5e-7 duty=0.5", "time=host_write", "its period is not between 1 µs and 1 h"),
        ("period_s=1.0 duty=1.5", "time=host_write", "its duty is not between 0 and 1"),
        ("period_s=1.0 duty=0", "time=host_write", "its duty is not between 0 and 1"),
        (
            "period_s=1e-5 duty=0.5",
            "rising_edges=99999999999999 time=host_write",
            r"it has more than 1e\+07 rising edges",
        ),
    ],
)
def test_a_wave_no_trigger_device_makes_is_refused_naming_the_file(tmp_path, start, stop, why):
    """An edited or damaged log (found by bench/fuzz.py): refused, never turned into edges (the
    simulated SPECT would have tried to allocate them all)."""
    p = write_log(
        tmp_path / "trigger.csv",
        [
            (0.0, "", "daqmx", "wave_start", start + " high_v=5.0 low_v=0.0 start_pulse=no time=host_write"),
            (3.0, "", "daqmx", "wave_stop", stop),
        ],
    )
    with pytest.raises(
        DataError,
        match=f"trigger.csv: the wave_start row of daqmx .* describes no wave a trigger"
        f" device makes: {why} .*edited or damaged",
    ):
        wave_from_trigger_log(p)


def test_a_wave_that_stops_before_it_starts_is_refused(tmp_path):
    start = "period_s=1.0 duty=0.5 high_v=5.0 low_v=0.0 start_pulse=no time=host_write"
    p = write_log(
        tmp_path / "trigger.csv",
        [(5.0, "", "daqmx", "wave_start", start), (-9.0, "", "daqmx", "wave_stop", "time=host_write")],
    )
    with pytest.raises(DataError, match="stops before it starts"):
        wave_from_trigger_log(p)


def test_an_old_function_generator_log_is_converted_on_read(tmp_path):
    """Written before the neutral rows: OUTP 1 starts the wave at the host time logged, OUTP 0 ends it."""
    p = write_log(
        tmp_path / "trigger.csv",
        [
            (0.0, "", "fgen", "cmd", "*IDN?"),
            (0.001, "", "fgen", "reply", "Agilent Technologies,33522B,X,1"),
            (0.01, "", "fgen", "cmd", "FREQ 2"),
            (0.02, "", "fgen", "cmd", "FUNC:SQU:DCYC 30"),
            (0.03, "", "fgen", "cmd", "VOLT:HIGH 2.5"),
            (0.04, "", "fgen", "cmd", "VOLT:LOW 0"),
            (1.0, "", "fgen", "cmd", "OUTP 1"),
            (4.2, "", "fgen", "cmd", "OUTP 0"),
        ],
    )
    w = wave_from_trigger_log(p)
    assert w.converted and "old log" in w.how
    assert (w.start_host, w.stop_host, w.period_s, w.duty, w.high_v, w.low_v) == (
        T0 + 1.0,
        T0 + 4.2,
        0.5,
        0.3,
        2.5,
        0.0,
    )
    assert (w.start_pulse, w.n_rising, w.time_source) == (False, None, HOST_WRITE)
    p = write_log(tmp_path / "nofreq.csv", [(1.0, "", "fgen", "cmd", "OUTP 1")])
    with pytest.raises(DataError, match="nofreq.csv: the frequency or duty of fgen's square wave is not in"):
        wave_from_trigger_log(p)


# ---- a backend defined here, registered with one line ----------------------------------------------


class ToySettings(BackendSettings):
    flavour: str = Field(default="plain", pattern=r"^[a-z]+$")


class ToyTrigger(TriggerBase):
    """A trigger generator in memory: what it starts and stops, it logs as neutral rows."""

    capabilities = frozenset({FREQUENCY, DUTY, LEVELS, FIRE})

    def __init__(self, address, flavour, log):
        super().__init__("toy", log)
        self.address, self.flavour = address, flavour
        self.wave = None
        self.running = False

    def configure(self, frequency_hz, duty=0.5, high_v=None, low_v=None):
        self.wave = (frequency_hz, duty, high_v, low_v)
        return self.status()

    def fire(self):
        t = self.log.clock()
        self.running = True
        f, d, hi, lo = self.wave
        self.log.wave_started(
            self.name,
            t,
            period_s=1 / f,
            duty=d,
            high_v=hi,
            low_v=lo,
            start_pulse=True,
            time_source=HOST_WRITE,
            uncertainty_s=0.0,
        )
        return self.status()

    def stop(self):
        if self.running:
            self.log.wave_stopped(
                self.name, self.log.clock(), rising_edges=None, time_source=HOST_WRITE, uncertainty_s=0.0
            )
        self.running = False
        return self.status()

    def start(self):  # pragma: no cover - the scan fires
        raise AssertionError("not used")

    def pulse(self, channel, ms):  # pragma: no cover
        raise AssertionError("not used")

    def status(self):
        f, d, hi, lo = self.wave or (None, None, None, None)
        return TriggerStatus("toy", self.running, f, d, hi, lo)


TOY = TriggerBackend(
    "toy",
    "a toy in this test",
    ToySettings,
    lambda cfg, settings, log: ToyTrigger(cfg.address, settings.flavour, log),
    levels=True,
)


@pytest.fixture()
def toy_registered(monkeypatch):
    monkeypatch.setitem(registry.TRIGGER_BACKENDS, "toy", TOY)  # the one line


def _rig_yaml(tmp_path, **trigger):
    p = tmp_path / "rig.yaml"
    p.write_text(yaml.safe_dump({"rig": "t", "cameras": [{"name": "cam1", "host": "127.0.0.1"}], "trigger": trigger}))
    return p


def test_a_backend_registered_with_one_line_is_opened_from_rig_yaml_and_used_by_the_scan(tmp_path, toy_registered):
    rig = load_rig(
        _rig_yaml(
            tmp_path,
            backend="toy",
            address="mem://1",
            flavour="sour",
            frequency_hz=2.0,
            duty=0.25,
            high_v=2.5,
            low_v=0.0,
        )
    )
    steps = {s.name: s.text for s in ScanSession(rig, tmp_path / "scan", []).plan()}
    assert steps["check trigger"].startswith("check the toy trigger, a toy in this test, at mem://1:")
    assert "configure 2 Hz, duty 0.25, levels 0..2.5 V" in steps["check trigger"]
    gen = registry.open_trigger(rig)
    assert isinstance(gen, ToyTrigger) and (gen.address, gen.flavour) == ("mem://1", "sour")

    trig = ScanTrigger(rig)  # what the scan session does with its trigger
    trig.check()
    trig.attach_log(tmp_path / "trigger.csv")
    trig.fire()
    trig.stop()
    trig.finish()
    assert trig.info["fired"] and trig.info["confirmed"]["high_v"] == 2.5 and trig.info["errors"] == []
    w = wave_from_trigger_log(tmp_path / "trigger.csv")
    assert (w.device, w.period_s, w.duty, w.high_v, w.low_v, w.start_pulse) == ("toy", 0.5, 0.25, 2.5, 0.0, True)
    assert w.stop_host is not None and w.stop_host >= w.start_host
    assert [r["kind"] for r in read_log(tmp_path / "trigger.csv")] == ["wave_start", "wave_stop"]


def test_a_backends_own_keys_are_checked_by_its_model_naming_the_file_and_key(tmp_path, toy_registered):
    path = _rig_yaml(tmp_path, backend="toy", address="mem://1", flavor="sour")
    rig = load_rig(path)  # the core does not know the toy's keys ...
    with pytest.raises(ConfigError, match=rf"^{path}: trigger.flavor is not a known key$"):
        registry.open_trigger(rig)  # ... its own model does, when it is opened
    rig = load_rig(_rig_yaml(tmp_path, backend="toy", address="mem://1", flavour="Sour"))
    with pytest.raises(
        ScanError,
        match=r"^cannot start the scan: .*rig.yaml: trigger.flavour string should "
        r"match pattern",
    ) as e:
        ScanSession(rig, tmp_path / "scan", []).trigger.check()
    assert e.value.exit_code == 2  # a config error, as the CLI exits
    rig = load_rig(_rig_yaml(tmp_path, backend="none", lines=["a", "b"]))
    with pytest.raises(ConfigError, match=r"trigger.lines is not a known key \(trigger backend none"):
        registry.trigger_settings(rig.trigger)


def test_an_unknown_backend_is_one_sentence_naming_the_file_and_key(tmp_path):
    path = _rig_yaml(tmp_path, backend="fancybox", address="/dev/ttyACM0")
    p = subprocess.run(
        [*VTS, "trigger", "status", "--config", str(path), "--log", str(tmp_path / "t.csv")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert p.stderr.strip() == (
        f"vts: {path}: trigger.backend 'fancybox' is not a trigger backend (known: none, daqmx, triggerbox, visa)"
    )
    path = _rig_yaml(tmp_path, backend="daqmx", address="Dev1/ctr0", lines=["Dev1/port0/line0"])
    p = subprocess.run(
        [*VTS, "scan", "start", "--dry-run", "--config", str(path)], capture_output=True, text=True, timeout=60
    )
    assert p.returncode == 0, p.stderr  # the plan names the backend; its keys are checked when opened
    p = subprocess.run(
        [*VTS, "trigger", "status", "--config", str(path), "--log", str(tmp_path / "t.csv")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 2 and p.stderr.strip() == f"vts: {path}: trigger.lines[1] is required but missing"
    assert len(p.stderr.strip().splitlines()) == 1
