"""The NI-DAQmx backend: our logic against a recording fake port, and (only where an NI-DAQmx driver
with a real or simulated device is present) against the real nidaqmx package."""

from __future__ import annotations

import os
import sys

import pytest

from vts_hw.drivers.daqmx import INSTALL_HINT, DaqmxPort, DaqmxTrigger, NidaqmxPort, no_driver_errors
from vts_hw.drivers.function_generator import OutOfRange
from vts_hw.drivers.trigger import (
    CLOCK,
    DUTY,
    FIRE,
    FREQUENCY,
    LEVELS,
    PULSE,
    TriggerError,
    TriggerGenerator,
    TriggerLog,
    Unsupported,
    read_log,
)

LINES = ("Dev1/port0/line0", "Dev1/port0/line1")
BOTH = "Dev1/port0/line0,Dev1/port0/line1"


class FakePort:
    """A DaqmxPort that records every call (in one list, with the fake clock's time) and
    answers like DAQmx would: coerced actual values, running from start to stop."""

    def __init__(self, clock=None, coerce=lambda f, d: (f, d)):
        self.calls: list[tuple] = []
        self.running = False
        self.configured = None
        self.clock = clock
        self.coerce = coerce
        self.fail_start = False

    def _rec(self, *call):
        self.calls.append(call + ((self.clock.t,) if self.clock else ()))

    def configure_pulse_train(self, counter, frequency_hz, duty, start_trigger=None):
        self._rec("configure", counter, frequency_hz, duty, start_trigger)
        self.configured = (counter, frequency_hz, duty, start_trigger)
        return self.coerce(frequency_hz, duty)

    def start_pulse_train(self):
        self._rec("start")
        if self.fail_start:
            raise TriggerError("NI-DAQmx starting the pulse train failed: simulated")
        self.running = True

    def stop_pulse_train(self):
        self._rec("stop")
        self.running = False

    def pulse_train_running(self):
        return self.running

    def write_lines(self, lines, values):
        self._rec("lines", lines, tuple(values))

    def close(self):
        self._rec("close")


class FakeClock:
    """A host clock that only moves when the trigger sleeps (or when told)."""

    def __init__(self):
        self.t = 100.0
        self.sleeps: list[float] = []

    def __call__(self):
        return self.t

    def sleep(self, s):
        self.sleeps.append(s)
        self.t += s


def names(calls):
    return [c[0] for c in calls]


@pytest.fixture()
def clock():
    return FakeClock()


@pytest.fixture()
def port(clock):
    return FakePort(clock)


def make(port, clock, **kw):
    kw.setdefault("lines", LINES)
    return DaqmxTrigger("Dev1/ctr0", port=port, sleep=clock.sleep, clock=clock, **kw)


# ---- our logic against the fake port ---------------------------------------------------------------


def test_the_fake_is_a_port_and_the_trigger_keeps_the_contract(port, clock):
    assert isinstance(port, DaqmxPort)
    trig = make(port, clock)
    assert isinstance(trig, TriggerGenerator)
    assert trig.capabilities == {FREQUENCY, DUTY, PULSE, FIRE}
    assert make(FakePort(), clock, lines=None).capabilities == {FREQUENCY, DUTY}


def test_configure_start_stop(port, clock):
    port.coerce = lambda f, d: (f * (1 + 1e-7), 0.5000001)  # DAQmx coerces to its timebase
    trig = make(port, clock)
    st = trig.configure(1.0, 0.5)
    assert port.calls[0][:5] == ("configure", "Dev1/ctr0", 1.0, 0.5, None)
    assert (st.running, st.frequency_hz, st.duty) == (False, 1.0000001, 0.5000001)
    assert st.extra["asked_frequency_hz"] == 1.0 and st.extra["asked_duty"] == 0.5
    st = trig.start()
    assert st.running and names(port.calls) == ["configure", "start"]
    assert not trig.stop().running and names(port.calls) == ["configure", "start", "stop"]


@pytest.mark.parametrize(
    "call",
    [
        pytest.param(lambda t: t.configure(0.001), id="frequency below 0.01 Hz"),
        pytest.param(lambda t: t.configure(6e6), id="frequency above 5 MHz"),
        pytest.param(lambda t: t.configure(float("inf")), id="frequency inf"),
        pytest.param(lambda t: t.configure("1 Hz"), id="frequency text"),
        pytest.param(lambda t: t.configure(1.0, 0.0), id="duty 0"),
        pytest.param(lambda t: t.configure(1.0, 1.0), id="duty 1"),
        pytest.param(lambda t: t.configure(1.0, 50), id="duty given in percent"),
        pytest.param(lambda t: t.configure(4e6, 0.2), id="duty 0.2 at 4 MHz (50 ns high)"),
        pytest.param(lambda t: t.pulse(1, 0), id="pulse 0 ms"),
        pytest.param(lambda t: t.pulse(2, 10_001), id="pulse over 10 s"),
        pytest.param(lambda t: t.pulse(1, 2.5), id="pulse 2.5 ms"),
    ],
)
def test_a_value_out_of_range_is_refused_before_any_call(port, clock, call):
    trig = make(port, clock)
    with pytest.raises(OutOfRange, match="nothing was sent"):
        call(trig)
    assert port.calls == []


def test_levels_channels_and_clock_are_refused_before_any_call(port, clock):
    trig = make(port, clock)
    with pytest.raises(Unsupported, match="daqmx cannot set output levels: .*TTL"):
        trig.configure(1.0, 0.5, high_v=5.0, low_v=0.0)
    with pytest.raises(ValueError, match="channel must be 1 .* or 2"):
        trig.pulse(3, 10)
    with pytest.raises(Unsupported, match="daqmx cannot report a device clock"):
        trig.clock_mapping()
    assert LEVELS not in trig.capabilities and CLOCK not in trig.capabilities
    no_lines = make(port, clock, lines=None)
    with pytest.raises(Unsupported, match="daqmx cannot send a start pulse"):
        no_lines.pulse(1, 10)
    with pytest.raises(Unsupported, match="daqmx cannot start the square wave and the start pulses together"):
        no_lines.fire()
    assert port.calls == []


def test_a_start_pulse_is_line_high_sleep_line_low(port, clock):
    trig = make(port, clock)
    trig.pulse(2, 150)
    assert port.calls == [("lines", BOTH, (False, True), 100.0), ("lines", BOTH, (False, False), 100.15)]
    assert clock.sleeps == [0.15]
    trig.pulse(1, 5)
    assert port.calls[2:] == [("lines", BOTH, (True, False), 100.15), ("lines", BOTH, (False, False), 100.155)]


def test_a_start_pulse_ends_even_if_the_wait_is_interrupted(port, clock):
    def interrupted(s):
        raise KeyboardInterrupt

    trig = DaqmxTrigger("Dev1/ctr0", lines=LINES, port=port, sleep=interrupted, clock=clock)
    with pytest.raises(KeyboardInterrupt):
        trig.pulse(1, 100)
    assert [c[2] for c in port.calls] == [(True, False), (False, False)]


def test_fire_with_a_hardware_start_trigger_arms_the_counter_before_the_lines_rise(port, clock):
    trig = make(port, clock, fire_trigger="/Dev1/PFI0", fire_pulse_ms=200)
    trig.configure(1.0, 0.5)
    st = trig.fire()
    assert [c[:-1] for c in port.calls] == [
        ("configure", "Dev1/ctr0", 1.0, 0.5, None),
        ("lines", BOTH, (False, False)),  # so there is a rising edge
        ("configure", "Dev1/ctr0", 1.0, 0.5, "/Dev1/PFI0"),  # armed on the line's edge
        ("start",),
        ("lines", BOTH, (True, True)),  # both start pulses, one write
        ("lines", BOTH, (False, False)),
    ]
    assert port.calls[-1][-1] - port.calls[-2][-1] == pytest.approx(0.2)
    assert st.running and st.extra["fire"] == "hardware start trigger on /Dev1/PFI0"
    # a later plain start() must not wait for a trigger edge
    trig.stop()
    trig.start()
    assert [c[:-1] for c in port.calls[-3:]] == [("stop",), ("configure", "Dev1/ctr0", 1.0, 0.5, None), ("start",)]


def test_fire_with_a_software_start_reports_its_skew(port, clock):
    trig = make(port, clock)
    trig.configure(2.0, 0.25)

    def slow_start():  # the counter start takes 3 ms
        FakePort.start_pulse_train(port)
        clock.t += 0.003

    port.start_pulse_train = slow_start
    st = trig.fire()
    assert [c[0] for c in port.calls] == ["configure", "lines", "lines", "start", "lines"]
    assert [c[2] for c in port.calls if c[0] == "lines"] == [(False, False), (True, True), (False, False)]
    assert st.extra["fire"] == "software start"
    assert st.extra["fire_skew_bound_s"] == pytest.approx(0.003)
    assert any("counter started within 3.000 ms" in r[4] for r in trig.log.lines)


def test_fire_lowers_the_lines_if_the_counter_does_not_start(port, clock):
    trig = make(port, clock)
    trig.configure(1.0, 0.5)
    port.fail_start = True
    with pytest.raises(TriggerError, match="simulated"):
        trig.fire()
    assert port.calls[-1][:3] == ("lines", BOTH, (False, False))


def test_fire_and_start_need_a_configured_wave_and_a_stopped_one(port, clock):
    trig = make(port, clock)
    with pytest.raises(TriggerError, match="configure\\(\\) first"):
        trig.fire()
    with pytest.raises(TriggerError, match="configure\\(\\) first"):
        trig.start()
    assert port.calls == []
    trig.configure(1.0, 0.5)
    trig.start()
    with pytest.raises(TriggerError, match="already running"):
        trig.fire()
    with pytest.raises(TriggerError, match="stop\\(\\) before configuring"):
        trig.configure(2.0, 0.5)


def test_close_stops_the_wave_lowers_the_lines_and_closes_the_port(port, clock):
    trig = make(port, clock)
    trig.configure(1.0, 0.5)
    trig.start()
    trig._line_state = [True, False]  # as if a pulse had been interrupted mid-way
    trig.close()
    assert [c[0] for c in port.calls[-3:]] == ["stop", "lines", "close"]
    assert port.calls[-2][2] == (False, False)
    trig.close()  # twice is fine
    assert port.calls[-1][0] == "close" and len([c for c in port.calls if c[0] == "close"]) == 1


def test_trigger_csv_lines(tmp_path, port, clock):
    path = tmp_path / "trigger.csv"
    with make(port, clock, log=TriggerLog(path)) as trig:
        trig.configure(1.0, 0.5)
        trig.pulse(1, 100)
    rows = [(r["device"], r["kind"], r["text"]) for r in read_log(path)]
    assert rows[0] == (
        "daqmx",
        "event",
        "open NI-DAQmx counter Dev1/ctr0, start-pulse lines Dev1/port0/line0 (1), Dev1/port0/line1 (2)",
    )
    assert rows[1:5] == [
        ("daqmx", "cmd", "CO Dev1/ctr0 pulse train freq=1.0 Hz duty=0.5 continuous idle low"),
        ("daqmx", "reply", "CO Dev1/ctr0 actual freq=1.0 Hz duty=0.5"),
        ("daqmx", "cmd", f"DO {BOTH} = 1,0"),
        ("daqmx", "cmd", f"DO {BOTH} = 0,0"),
    ]
    assert rows[5] == (
        "daqmx",
        "event",
        "pulse channel 1 (VTS start) 100 ms: 100.000 ms between the writes (host clock)",
    )
    assert rows[-1] == ("daqmx", "event", "closed")


def test_bad_construction_is_refused():
    with pytest.raises(ValueError, match="two different digital lines"):
        DaqmxTrigger("Dev1/ctr0", lines=("Dev1/port0/line0", "Dev1/port0/line0"), port=FakePort())
    with pytest.raises(ValueError, match="two different digital lines"):
        DaqmxTrigger("Dev1/ctr0", lines=("Dev1/port0/line0",), port=FakePort())
    with pytest.raises(ValueError, match="fire_trigger needs the start-pulse lines"):
        DaqmxTrigger("Dev1/ctr0", fire_trigger="/Dev1/PFI0", port=FakePort())
    with pytest.raises(ValueError, match="physical counter"):
        DaqmxTrigger("", port=FakePort())


# ---- the real nidaqmx package ------------------------------------------------------------------------


def test_without_nidaqmx_the_port_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "nidaqmx", None)  # import nidaqmx -> ImportError
    with pytest.raises(TriggerError, match=r"needs the nidaqmx package: pip install vts-hw\[daqmx\]"):
        NidaqmxPort()
    with pytest.raises(TriggerError, match=r"pip install vts-hw\[daqmx\]"):
        DaqmxTrigger("Dev1/ctr0")  # the default port is the real one
    assert "vts-hw[daqmx]" in INSTALL_HINT


def _nidaqmx():
    try:
        import nidaqmx
        import nidaqmx.errors
        import nidaqmx.system
    except ImportError:
        pytest.skip("nidaqmx is not installed (it is the optional extra: pip install vts-hw[daqmx])")
    return nidaqmx


def _driver_missing_reason(nidaqmx) -> str | None:
    try:
        nidaqmx.system.System.local().driver_version
    except no_driver_errors(nidaqmx) as e:
        return f"no NI-DAQmx driver (libnidaqmx) on this machine: {e}"
    return None


def test_with_nidaqmx_but_no_driver_the_port_says_so():
    nidaqmx = _nidaqmx()
    reason = _driver_missing_reason(nidaqmx)
    if reason is None:
        pytest.skip("an NI-DAQmx driver is installed here")
    with pytest.raises(TriggerError, match=r"no NI-DAQmx driver \(libnidaqmx\) on this machine"):
        NidaqmxPort()


def test_nidaqmx_port_calls_the_nidaqmx_api_as_its_signatures_say(monkeypatch):
    """Runs where the nidaqmx package is installed, driver or not: the tasks are autospecced from
    nidaqmx's own classes, so a wrong method name or argument fails here, not first on a rig."""
    nidaqmx = _nidaqmx()
    from unittest import mock

    from nidaqmx.constants import AcquisitionType, Edge, Level, LineGrouping, TaskMode
    from nidaqmx.task import Timing
    from nidaqmx.task.channels import COChannel
    from nidaqmx.task.collections import COChannelCollection, DOChannelCollection
    from nidaqmx.task.triggering import StartTrigger, Triggers

    tasks = []
    real_task = nidaqmx.Task

    def spec_task(*args, **kwargs):
        t = mock.create_autospec(real_task, instance=True)
        t.co_channels = mock.create_autospec(COChannelCollection, instance=True)
        co = mock.create_autospec(COChannel, instance=True)
        co.co_pulse_freq, co.co_pulse_duty_cyc = 0.99999996, 0.5
        t.co_channels.add_co_pulse_chan_freq.return_value = co
        t.timing = mock.create_autospec(Timing, instance=True)
        t.triggers = mock.create_autospec(Triggers, instance=True)
        t.triggers.start_trigger = mock.create_autospec(StartTrigger, instance=True)
        t.do_channels = mock.create_autospec(DOChannelCollection, instance=True)
        t.do_channels.channel_names = list(LINES)
        t.is_task_done.return_value = False
        tasks.append(t)
        return t

    monkeypatch.setattr(nidaqmx, "Task", spec_task)
    monkeypatch.setattr(nidaqmx.system.System, "local", staticmethod(lambda: mock.Mock(driver_version="23.8.0")))

    port = NidaqmxPort()
    assert isinstance(port, DaqmxPort)
    assert port.configure_pulse_train("Dev1/ctr0", 1.0, 0.5, "/Dev1/PFI0") == (0.99999996, 0.5)
    co = tasks[0]
    co.co_channels.add_co_pulse_chan_freq.assert_called_once_with(
        "Dev1/ctr0", idle_state=Level.LOW, initial_delay=0.0, freq=1.0, duty_cycle=0.5
    )
    co.timing.cfg_implicit_timing.assert_called_once_with(sample_mode=AcquisitionType.CONTINUOUS)
    co.triggers.start_trigger.cfg_dig_edge_start_trig.assert_called_once_with("/Dev1/PFI0", trigger_edge=Edge.RISING)
    co.control.assert_called_once_with(TaskMode.TASK_COMMIT)
    assert not port.pulse_train_running()
    port.start_pulse_train()
    co.start.assert_called_once_with()
    assert port.pulse_train_running()

    port.write_lines(BOTH, [True, False])
    port.write_lines(BOTH, [False, False])
    do = tasks[1]
    assert len(tasks) == 2  # one static DO task, reused
    do.do_channels.add_do_chan.assert_called_once_with(BOTH, line_grouping=LineGrouping.CHAN_PER_LINE)
    do.start.assert_called_once_with()
    assert do.write.call_args_list == [mock.call([True, False]), mock.call([False, False])]
    with pytest.raises(TriggerError, match="has 2 lines, 1 values given"):
        port.write_lines(BOTH, [True])

    port.configure_pulse_train("Dev1/ctr0", 2.0, 0.25)  # a new task replaces the old one
    co.close.assert_called_once_with()
    tasks[2].triggers.start_trigger.cfg_dig_edge_start_trig.assert_not_called()
    tasks[2].start.side_effect = nidaqmx.errors.DaqError("Resource is reserved", -50103)
    with pytest.raises(TriggerError, match="NI-DAQmx starting the pulse train failed: Resource is reserved"):
        port.start_pulse_train()
    port.close()
    tasks[2].close.assert_called_once_with()
    do.close.assert_called_once_with()


@pytest.fixture()
def daq_device():
    """A real or simulated NI-DAQmx device with a counter and two digital lines, else skip.

    VTS_DAQMX_DEVICE picks one by name; otherwise the first that has what is needed."""
    nidaqmx = _nidaqmx()
    reason = _driver_missing_reason(nidaqmx)
    if reason:
        pytest.skip(reason)
    try:
        devices = list(nidaqmx.system.System.local().devices)
    except nidaqmx.errors.DaqError as e:
        pytest.skip(f"NI-DAQmx cannot list its devices: {e}")
    wanted = os.environ.get("VTS_DAQMX_DEVICE")
    for dev in devices:
        if wanted and dev.name != wanted:
            continue
        try:
            counters = dev.co_physical_chans.channel_names
            lines = dev.do_lines.channel_names
        except nidaqmx.errors.DaqError:
            continue
        if counters and len(lines) >= 2:
            return dev.name, counters[0], (lines[0], lines[1])
    pytest.skip(
        "NI-DAQmx has no device with a counter output and two digital lines (add a simulated "
        "one, e.g. a PCIe-6363, in NI MAX or with nidaqmx's device tools; VTS_DAQMX_DEVICE "
        "picks one by name)"
    )


def test_real_nidaqmx_configure_start_pulse_fire_stop(daq_device, tmp_path):
    _name, counter, lines = daq_device
    log = TriggerLog(tmp_path / "trigger.csv")
    with DaqmxTrigger(counter, lines=lines, log=log, fire_pulse_ms=20) as trig:
        st = trig.configure(1.0, 0.5)
        assert st.frequency_hz == pytest.approx(1.0, rel=1e-3) and st.duty == pytest.approx(0.5, rel=1e-3)
        assert trig.start().running
        assert not trig.stop().running
        trig.pulse(1, 10)
        trig.pulse(2, 10)
        st = trig.fire()  # software start: simulated devices do not route triggers
        assert st.running and st.extra["fire"] == "software start"
        assert st.extra["fire_skew_bound_s"] >= 0
        assert not trig.stop().running
    kinds = {r["kind"] for r in read_log(tmp_path / "trigger.csv")}
    assert {"cmd", "reply", "event"} <= kinds


def test_the_rig_configs_pulse_width_reaches_the_daqmx_fire(monkeypatch, clock):
    """rig.yaml's trigger.pulse_ms is the width of the start pulses fire() sends (it was
    always the driver's 100 ms default)."""
    from vts_hw.config import TriggerConfig
    from vts_hw.drivers import daqmx
    from vts_hw.drivers.registry import open_trigger

    port = FakePort(clock)
    monkeypatch.setattr(daqmx, "NidaqmxPort", lambda: port)
    trig = open_trigger(TriggerConfig(backend="daqmx", address="Dev1/ctr0", lines=LINES, pulse_ms=250))
    assert trig.fire_pulse_ms == 250
    trig._sleep, trig._clock = clock.sleep, clock  # the fake clock moves only when it sleeps
    trig.configure(1.0, 0.5)
    trig.fire()
    rises = [c for c in port.calls if c[0] == "lines" and c[2] == (True, True)]
    falls = [c for c in port.calls if c[0] == "lines" and c[2] == (False, False) and c[-1] > rises[0][-1]]
    assert falls[0][-1] - rises[0][-1] == pytest.approx(0.25)
