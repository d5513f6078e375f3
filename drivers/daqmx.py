"""NI-DAQmx as a trigger generator: a counter-output pulse train for the square wave, digital lines
for the start pulses (the optional extra ``daqmx``: ``pip install vts-hw[daqmx]``).

Two layers:

- :class:`DaqmxPort` — the small interface to the hardware: configure/start/stop a continuous
  counter-output pulse train, write digital lines, close. :class:`NidaqmxPort` implements it
  with the ``nidaqmx`` package (imported only when a port is made); tests use a fake.
- :class:`DaqmxTrigger` — the trigger contract on top of a port: range checks before any
  call, start pulses of N ms, fire, status, the ``trigger.csv`` lines.

Timing, honestly (docs/decisions/0010):

- The square wave is hardware-timed by the counter; DAQmx coerces frequency and duty to its
  timebase and the values it reports after committing the task are what we return.
- A start pulse is host-timed: line high, sleep, line low. Its width is the asked ms plus the
  host's scheduling and the device's write latency (not bounded on a loaded machine). The host
  time between the two writes is logged for every pulse.
- ``fire`` with ``fire_trigger`` (a PFI terminal wired to, or internally routed from, one of
  the start-pulse lines): the counter is armed with a digital-edge start trigger on that
  terminal, then both start-pulse lines rise in one write; the wave starts in hardware on that
  edge (skew: the trigger routing plus the counter's initial delay of a few timebase ticks,
  expected well under 1 us). Without ``fire_trigger``: a software start — both lines rise, then the
  counter task is started; the skew is bounded by the host time between the two calls, which
  is measured and returned (``extra["fire_skew_bound_s"]``) and logged.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, Protocol, runtime_checkable

from pydantic import Field

from vts_hw.drivers.trigger import (
    CHANNELS,
    DUTY,
    FIRE,
    FREQUENCY,
    LEVELS,
    PULSE,
    BackendSettings,
    OutOfRange,
    TriggerBackend,
    TriggerBase,
    TriggerError,
    TriggerLog,
    TriggerStatus,
)
from vts_hw.recording.trigger_log import HOST_WRITE

INSTALL_HINT = "pip install vts-hw[daqmx]"

# Ranges common to NI M- and X-series counters (the device's own limits may be wider; DAQmx
# refuses or coerces what the device cannot do, and that comes back as TriggerError or as the
# actual values).
FREQ_MIN_HZ = 0.01  # 100 s period: fits a 24-bit counter on the 100 kHz timebase
FREQ_MAX_HZ = 5e6
DUTY_MIN = 1e-4
DUTY_MAX = 1.0 - 1e-4
MIN_PULSE_S = 100e-9  # high and low time: 2 ticks of a 20 MHz timebase
PULSE_MS_MIN = 1
PULSE_MS_MAX = 10_000
TTL_HIGH_V, TTL_LOW_V = 5.0, 0.0  # nominal TTL levels, as the neutral log rows state them


@runtime_checkable
class DaqmxPort(Protocol):
    """The hardware under :class:`DaqmxTrigger`: one counter output, one set of digital lines."""

    def configure_pulse_train(
        self, counter: str, frequency_hz: float, duty: float, start_trigger: str | None = None
    ) -> tuple[float, float]:
        """Set up (not start) a continuous pulse train on ``counter``, idle low; with
        ``start_trigger`` it waits, once started, for a rising edge on that terminal.
        Returns (frequency, duty) as the device will generate them."""
        ...

    def start_pulse_train(self) -> None: ...

    def stop_pulse_train(self) -> None: ...

    def pulse_train_running(self) -> bool:
        """True from start until stop (including armed and waiting for its start trigger)."""
        ...

    def write_lines(self, lines: str, values: Sequence[bool]) -> None:
        """Set the digital ``lines`` (comma-separated physical names) in one write."""
        ...

    def close(self) -> None: ...


def no_driver_errors(nidaqmx) -> tuple[type[BaseException], ...]:
    """The nidaqmx exceptions that mean "no NI-DAQmx driver here" (by nidaqmx version)."""
    return tuple(
        getattr(nidaqmx.errors, n) for n in ("DaqNotFoundError", "DaqNotSupportedError") if hasattr(nidaqmx.errors, n)
    )


class NidaqmxPort:
    """:class:`DaqmxPort` on the ``nidaqmx`` package and the NI-DAQmx driver."""

    def __init__(self):
        try:
            import nidaqmx
            import nidaqmx.constants
            import nidaqmx.errors
            import nidaqmx.system
        except ImportError as e:
            raise TriggerError(f"the NI-DAQmx backend needs the nidaqmx package: {INSTALL_HINT} ({e})") from e
        self._nidaqmx = nidaqmx
        self._const = nidaqmx.constants
        self._errors = nidaqmx.errors
        try:
            self.driver_version = str(nidaqmx.system.System.local().driver_version)
        except no_driver_errors(nidaqmx) as e:
            raise TriggerError(
                f"no NI-DAQmx driver (libnidaqmx) on this machine: install NI-DAQmx from NI, then {INSTALL_HINT} ({e})"
            ) from e
        except nidaqmx.errors.Error as e:
            raise TriggerError(f"NI-DAQmx is installed but does not answer: {e}") from e
        self._co = None  # the counter-output task
        self._co_started = False
        self._do: dict[str, Any] = {}  # lines -> started static digital-output task

    @contextmanager
    def _daq(self, what: str) -> Iterator[None]:
        try:
            yield
        except self._errors.Error as e:
            raise TriggerError(f"NI-DAQmx {what} failed: {e}") from e

    def configure_pulse_train(self, counter, frequency_hz, duty, start_trigger=None):
        c = self._const
        with self._daq(f"configuring the pulse train on {counter}"):
            self._close_co()
            task = self._nidaqmx.Task()
            try:
                ch = task.co_channels.add_co_pulse_chan_freq(
                    counter, idle_state=c.Level.LOW, initial_delay=0.0, freq=frequency_hz, duty_cycle=duty
                )
                task.timing.cfg_implicit_timing(sample_mode=c.AcquisitionType.CONTINUOUS)
                if start_trigger:
                    task.triggers.start_trigger.cfg_dig_edge_start_trig(start_trigger, trigger_edge=c.Edge.RISING)
                task.control(c.TaskMode.TASK_COMMIT)  # DAQmx coerces to its timebase here
                actual = (float(ch.co_pulse_freq), float(ch.co_pulse_duty_cyc))
            except BaseException:
                task.close()
                raise
            self._co = task
            return actual

    def start_pulse_train(self):
        if self._co is None:
            raise TriggerError("NI-DAQmx: no pulse train configured")
        with self._daq("starting the pulse train"):
            self._co.start()
            self._co_started = True

    def stop_pulse_train(self):
        if self._co is not None and self._co_started:
            with self._daq("stopping the pulse train"):
                self._co.stop()
        self._co_started = False

    def pulse_train_running(self):
        if self._co is None or not self._co_started:
            return False
        with self._daq("reading the pulse train's state"):
            return not self._co.is_task_done()

    def write_lines(self, lines, values):
        with self._daq(f"writing {lines}"):
            task = self._do.get(lines)
            if task is None:
                task = self._nidaqmx.Task()
                try:
                    task.do_channels.add_do_chan(lines, line_grouping=self._const.LineGrouping.CHAN_PER_LINE)
                    task.start()
                except BaseException:
                    task.close()
                    raise
                self._do[lines] = task
            n = len(task.do_channels.channel_names)
            if n != len(values):
                raise TriggerError(f"NI-DAQmx: {lines} has {n} lines, {len(values)} values given")
            task.write([bool(v) for v in values] if n > 1 else bool(values[0]))

    def _close_co(self):
        if self._co is not None:
            try:
                self._co.close()
            finally:
                self._co = None
                self._co_started = False

    def close(self):
        with self._daq("closing tasks"):
            try:
                self._close_co()
            finally:
                tasks, self._do = list(self._do.values()), {}
                for t in tasks:
                    t.close()


class DaqmxTrigger(TriggerBase):
    """The trigger contract on an NI-DAQmx device: square wave on a counter, start pulses on lines.

    ``counter`` is a physical counter (``"Dev1/ctr0"``); the wave comes out on its default
    output terminal. ``lines`` are the start-pulse lines for channel 1 (VTS) and channel 2
    (SPECT), e.g. ``("Dev1/port0/line0", "Dev1/port0/line1")``; without them the backend can
    only make the square wave. ``fire_trigger`` is the terminal the counter's start trigger
    listens to in :meth:`fire` (see the module text); ``None`` means a software start.
    """

    def __init__(
        self,
        counter: str,
        *,
        lines: tuple[str, str] | None = None,
        fire_trigger: str | None = None,
        fire_pulse_ms: int = 100,
        port: DaqmxPort | None = None,
        name: str = "daqmx",
        log: TriggerLog | None = None,
        sleep: Callable[[float], None] = time.sleep,
        clock: Callable[[], float] = time.perf_counter,
    ):
        super().__init__(name, log)
        if not isinstance(counter, str) or not counter.strip():
            raise ValueError(f"counter must be a physical counter name such as 'Dev1/ctr0', not {counter!r}")
        if lines is not None:
            if (
                not isinstance(lines, (tuple, list))
                or len(lines) != 2
                or not all(isinstance(x, str) and x.strip() and "," not in x for x in lines)
                or lines[0] == lines[1]
            ):
                raise ValueError(
                    "lines must be two different digital lines, one for channel 1 (VTS "
                    f"start) and one for channel 2 (SPECT start), not {lines!r}"
                )
            lines = (lines[0], lines[1])
        if fire_trigger is not None and lines is None:
            raise ValueError("fire_trigger needs the start-pulse lines (lines=...)")
        self.counter = counter
        self.lines = lines
        self.fire_trigger = fire_trigger
        self.fire_pulse_ms = self._check_ms(fire_pulse_ms)
        self.capabilities = frozenset({FREQUENCY, DUTY} | ({PULSE, FIRE} if lines else set()))
        self._sleep = sleep
        self._clock = clock
        self._asked: tuple[float, float] | None = None
        self._actual: tuple[float, float] | None = None
        self._trigger_in_task: str | None = None
        self._line_state = [False, False]
        self._last_fire: dict[str, Any] = {}
        self._started: float | None = None  # host time of the wave's start, while it runs
        self._closed = False
        self.port: DaqmxPort = port if port is not None else NidaqmxPort()
        self.log.write(
            name,
            "event",
            f"open NI-DAQmx counter {counter}"
            + (f", start-pulse lines {lines[0]} (1), {lines[1]} (2)" if lines else ""),
        )

    def __repr__(self) -> str:
        return f"<DaqmxTrigger {self.name} {self.counter} lines={self.lines}>"

    # -- the trigger contract --------------------------------------------------------------------

    def configure(
        self, frequency_hz: float, duty: float = 0.5, high_v: float | None = None, low_v: float | None = None
    ) -> TriggerStatus:
        self.require(FREQUENCY)
        self.require(DUTY)
        if high_v is not None or low_v is not None:
            self.require(LEVELS, "set output levels: NI counter and digital outputs have fixed TTL levels")
        f, d = self._check_wave(frequency_hz, duty)
        if self.port.pulse_train_running():
            raise TriggerError(f"{self.name}: the square wave is running; stop() before configuring it again")
        self._configure_train(f, d, None)
        return self.status()

    def start(self) -> TriggerStatus:
        """The square wave alone (a software start of the counter task)."""
        asked = self._need_configured()
        if self.port.pulse_train_running():
            raise TriggerError(f"{self.name}: the square wave is already running")
        if self._trigger_in_task is not None:  # left armed by fire(): start without it
            self._configure_train(*asked, None)
        self._cmd(f"CO {self.counter} start")
        t0 = self.log.clock()
        self.port.start_pulse_train()
        t1 = self.log.clock()
        st = self.status()
        if not st.running:
            raise TriggerError(f"{self.name}: the counter task was started but reports done")
        self._wave_started(t0, t1, start_pulse=False)
        return st

    def stop(self) -> TriggerStatus:
        """Stop the counter task: the output goes to its idle level at once, mid-period if need be."""
        self._cmd(f"CO {self.counter} stop")
        t0 = self.log.clock()
        self.port.stop_pulse_train()
        t1 = self.log.clock()
        if self._started is not None:  # the output idles at once: the wave is cut there
            self._started = None
            self.log.wave_stopped(self.name, t0, rising_edges=None, time_source=HOST_WRITE, uncertainty_s=t1 - t0)
        st = self.status()
        if st.running:
            raise TriggerError(f"{self.name}: the counter task was stopped but reports running")
        return st

    def pulse(self, channel: int, ms: int) -> None:
        """A start pulse of ``ms`` on channel 1 (VTS) or 2 (SPECT): line high, sleep, line low."""
        self.require(PULSE)
        self.check_channel(channel)
        ms = self._check_ms(ms)
        i = channel - 1
        on = list(self._line_state)
        on[i] = True
        t_on = self._set_lines(on)
        try:
            self._sleep(ms / 1000.0)
        finally:
            off = list(self._line_state)
            off[i] = False
            t_off = self._set_lines(off)
        self.log.write(
            self.name,
            "event",
            f"pulse channel {channel} ({CHANNELS[channel]}) {ms} ms: "
            f"{(t_off - t_on) * 1e3:.3f} ms between the writes (host clock)",
        )

    def fire(self) -> TriggerStatus:
        """Square wave and both start pulses together (hardware start trigger if ``fire_trigger``)."""
        self.require(FIRE)
        f, d = self._need_configured()
        if self.port.pulse_train_running():
            raise TriggerError(f"{self.name}: the square wave is already running; stop() before fire()")
        self._set_lines([False, False])  # so that there is a rising edge
        if self.fire_trigger is not None:
            self._configure_train(f, d, self.fire_trigger)
            self._cmd(f"CO {self.counter} start (armed: starts on the rising edge of {self.fire_trigger})")
            self.port.start_pulse_train()
            h0 = self.log.clock()
            t_on = self._set_lines([True, True])  # the counter starts on this edge
            h1 = self.log.clock()
            self._last_fire = {"fire": f"hardware start trigger on {self.fire_trigger}"}
        else:
            if self._trigger_in_task is not None:
                self._configure_train(f, d, None)
            t0 = self._clock()
            t_on = self._set_lines([True, True])
            self._cmd(f"CO {self.counter} start")
            h0 = self.log.clock()
            try:
                self.port.start_pulse_train()
            except BaseException:
                self._set_lines([False, False])
                raise
            h1 = self.log.clock()
            skew = self._clock() - t0
            self._last_fire = {"fire": "software start", "fire_skew_bound_s": skew}
            self.log.write(
                self.name,
                "event",
                f"fire: software start, counter started within "
                f"{skew * 1e3:.3f} ms of the start-pulse write (host clock)",
            )
        try:
            self._sleep(self.fire_pulse_ms / 1000.0)
        finally:
            t_off = self._set_lines([False, False])
        self.log.write(
            self.name,
            "event",
            f"fire: start pulses {self.fire_pulse_ms} ms: "
            f"{(t_off - t_on) * 1e3:.3f} ms between the writes (host clock)",
        )
        st = self.status()
        if not st.running:
            raise TriggerError(f"{self.name}: fire() started the counter task but it reports done")
        self._wave_started(h0, h1, start_pulse=True)
        return st

    def _wave_started(self, h0: float, h1: float, start_pulse: bool) -> None:
        """``wave_start``: the counter starts during the call (or the line write that triggers
        it) between host times ``h0`` and ``h1``; DAQmx reports no edge times."""
        if self._actual is None:  # set with _asked by configure()
            raise TriggerError(f"{self.name}: no square wave configured: call configure() first")
        f, d = self._actual
        self._started = h0
        self.log.wave_started(
            self.name,
            h0,
            period_s=1.0 / f,
            duty=d,
            high_v=TTL_HIGH_V,
            low_v=TTL_LOW_V,
            start_pulse=start_pulse,
            time_source=HOST_WRITE,
            uncertainty_s=h1 - h0,
        )

    def status(self) -> TriggerStatus:
        running = bool(self.port.pulse_train_running())
        extra: dict[str, Any] = {"counter": self.counter, "lines": self.lines}
        if self._asked is not None:
            extra.update(asked_frequency_hz=self._asked[0], asked_duty=self._asked[1])
        extra.update(self._last_fire)
        f, d = self._actual if self._actual is not None else (None, None)
        return TriggerStatus(device=self.name, running=running, frequency_hz=f, duty=d, extra=extra)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            try:
                if self.port.pulse_train_running():
                    self.stop()
            finally:
                if self.lines is not None and any(self._line_state):
                    self._set_lines([False, False])
        finally:
            try:
                self.port.close()
            finally:
                self.log.write(self.name, "event", "closed")
                super().close()

    # -- checks -------------------------------------------------------------------------------------

    def _check_wave(self, frequency_hz: Any, duty: Any) -> tuple[float, float]:
        f = self._number(frequency_hz, "frequency", "Hz")
        d = self._number(duty, "duty", "(fraction)")
        if not FREQ_MIN_HZ <= f <= FREQ_MAX_HZ:
            raise OutOfRange(
                f"{self.name}: frequency {f:g} Hz is outside {FREQ_MIN_HZ:g} to {FREQ_MAX_HZ:g} Hz; nothing was sent"
            )
        low = max(DUTY_MIN, MIN_PULSE_S * f)
        high = min(DUTY_MAX, 1.0 - MIN_PULSE_S * f)
        if not low <= d <= high:
            raise OutOfRange(f"{self.name}: duty {d:g} is outside {low:g} to {high:g} at {f:g} Hz; nothing was sent")
        return f, d

    def _number(self, value: Any, what: str, unit: str) -> float:
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise OutOfRange(f"{self.name}: {what} must be a number {unit}, not {value!r}; nothing was sent") from None
        if not math.isfinite(v):
            raise OutOfRange(f"{self.name}: {what} must be finite, not {value!r}; nothing was sent")
        return v

    def _check_ms(self, ms: Any) -> int:
        if isinstance(ms, bool) or not isinstance(ms, int) or not PULSE_MS_MIN <= ms <= PULSE_MS_MAX:
            raise OutOfRange(
                f"{self.name}: a start pulse is {PULSE_MS_MIN} to {PULSE_MS_MAX} whole ms, not {ms!r}; nothing was sent"
            )
        return ms

    def _need_configured(self) -> tuple[float, float]:
        """The frequency and duty asked for by configure() (TriggerError before it)."""
        if self._asked is None:
            raise TriggerError(f"{self.name}: no square wave configured: call configure() first")
        return self._asked

    # -- the port, logged ---------------------------------------------------------------------------

    def _cmd(self, text: str) -> None:
        self.log.write(self.name, "cmd", text)

    def _configure_train(self, f: float, d: float, trigger: str | None) -> None:
        self._cmd(
            f"CO {self.counter} pulse train freq={f!r} Hz duty={d!r} continuous idle low"
            + (f" start trigger rising edge {trigger}" if trigger else "")
        )
        af, ad = self.port.configure_pulse_train(self.counter, f, d, trigger)
        self.log.write(self.name, "reply", f"CO {self.counter} actual freq={af!r} Hz duty={ad!r}")
        self._asked = (f, d)
        self._actual = (float(af), float(ad))
        self._trigger_in_task = trigger

    def _set_lines(self, values: list[bool]) -> float:
        """Write both start-pulse lines in one call; the host time just after the write."""
        assert self.lines is not None
        joined = ",".join(self.lines)
        self._cmd(f"DO {joined} = {','.join('1' if v else '0' for v in values)}")
        self.port.write_lines(joined, list(values))
        t = self._clock()
        self._line_state = list(values)
        return t


# ---- the backend (vts_hw.drivers.registry.TRIGGER_BACKENDS["daqmx"]) ----------------------------------


class DaqmxSettings(BackendSettings):
    """NI-DAQmx's own keys in rig.yaml's ``trigger:`` section (``address``: the counter, e.g.
    ``Dev1/ctr0``)."""

    lines: tuple[str, str] | None = Field(
        default=None, description="digital lines of start channels 1 and 2, e.g. Dev1/port0/line0"
    )
    fire_trigger: str | None = Field(
        default=None, description="terminal that starts the counter with the start pulses, e.g. /Dev1/PFI0"
    )


def _open_daqmx(cfg, settings: DaqmxSettings, log) -> DaqmxTrigger:
    return DaqmxTrigger(
        cfg.address, lines=settings.lines, fire_trigger=settings.fire_trigger, fire_pulse_ms=cfg.pulse_ms, log=log
    )


BACKEND = TriggerBackend("daqmx", "an NI-DAQmx counter and digital lines", DaqmxSettings, _open_daqmx)
