"""The steps of commissioning (procedures/commission.py), one function each, named after the
step: each calls what its own command calls and returns an :class:`Outcome`. Cameras are
opened here through the registry and closed before the step returns."""

from __future__ import annotations

import contextlib
import json
import time
from pathlib import Path

from vts_hw import catalog
from vts_hw.camera import Parameters, RunningTime, Setup
from vts_hw.camera_led import switch_led
from vts_hw.drivers.axis_uptime import NoUptime
from vts_hw.drivers.discovery import search
from vts_hw.drivers.registry import check_camera_kinds, kind_has, open_cameras, open_trigger
from vts_hw.errors import ConfigError, UsageError, VtsError
from vts_hw.files import WriteFailed, ensure_dir, write_atomic
from vts_hw.procedures import calibration as calibration_procedure
from vts_hw.procedures.aim import check as aim_check
from vts_hw.procedures.baseline import take_baselines
from vts_hw.procedures.commission import Context, Outcome, StepCheck
from vts_hw.procedures.drift import LED_SETTLE_S
from vts_hw.procedures.mapping_inputs import calibrated_cameras, camera_calibration_for, mapping_from_cameras
from vts_hw.procedures.step_test import run_step_test, step_test_inputs
from vts_hw.procedures.steps import step_plan
from vts_hw.procedures.sync import SyncAnalysis, check_session
from vts_hw.procedures.warmup import Watch, settle_wait_min
from vts_hw.procedures.warmup_clock import ClockWatch, judge_clock
from vts_hw.results import Measure
from vts_hw.rig_file import set_calibration, set_locked_params
from vts_hw.save_or_keep import save_or_keep
from vts_hw.tolerance import State

OK, TOL, ACT = State.OK, State.TOLERANCE, State.ACTION


def _json(path: Path, data) -> Path:
    return write_atomic(path, json.dumps(data, indent=2, default=str) + "\n")


def _need(what: str, option: str, how: str) -> UsageError:
    return UsageError(f"the {what} needs {option}: {how}; then `vts commission --resume` with it")


@contextlib.contextmanager
def _cameras(ctx: Context, cfgs, clock=None):
    """The cameras of ``cfgs``: the room's when the application gave them (``ctx.camera``: the
    room closes them), else opened here and closed after the step."""
    if ctx.camera is not None:
        check_camera_kinds(cfgs)
        yield [ctx.camera(cfg) for cfg in cfgs]
        return
    cams = open_cameras(cfgs, clock=clock)
    try:
        yield cams
    finally:
        for c in cams:
            c.close()


@contextlib.contextmanager
def _trigger(ctx: Context):
    """The rig's trigger generator: the room's (``ctx.trigger``), else opened and closed here."""
    if ctx.trigger is not None:
        yield ctx.trigger()
        return
    with contextlib.closing(open_trigger(ctx.rig)) as gen:  # what TriggerBase's __exit__ does
        yield gen


# ------------------------------------------------------------------ 1. cameras


def cameras(ctx: Context) -> Outcome:
    """`vts discover` (who announces itself) and `vts camera setup --all` (set, read back, lock
    into rig.yaml): each rig camera confirmed over VAPIX, its model, serial, firmware and the
    parameters locked written to devices.json for the report."""
    rig, inp = ctx.rig, ctx.inputs
    source = getattr(rig, "_source", None)
    if source is None:
        raise UsageError(
            "commissioning needs the rig config as a file (--config rig.yaml): locked_params are written into it"
        )
    for cfg in rig.cameras:
        if not kind_has(cfg, Setup):
            lacks = "no setup" if kind_has(cfg, Parameters) else "no parameters"
            raise UsageError(
                f"camera {cfg.name} is of kind {cfg.kind}, which has {lacks}: only Axis cameras are commissioned"
            )
        cfg.password()
    announced: dict[tuple[str | None, int], tuple[str, ...]] = {}  # looked up by the entry's host
    if inp.listen_s > 0:
        ctx.say(f"  listening {inp.listen_s:g} s for cameras announcing themselves (mDNS, SSDP)")
        for f in search(inp.listen_s, list(inp.interfaces) or None):
            announced[(f.host, f.port)] = f.sources
    devices, measures, lines, locked = [], [], [], {}
    for cfg in rig.cameras:
        with _cameras(ctx, [cfg]) as (cam,):
            info = cam.device_info()
            assert isinstance(cam, Setup)  # (its kind has the role: checked above)
            result = cam.set_up(cfg, rig.camera_setup)
        locked[cfg.name] = result.locked
        seen = announced.get((cfg.host, cfg.port))
        dev = {
            "name": cfg.name,
            "address": f"{cfg.host}:{cfg.port}",
            "model": info.get("ProdShortName") or info.get("ProdNbr") or info.get("Product") or "?",
            "serial": (info.get("SerialNumber") or "?").upper(),
            "firmware": info.get("Version") or "?",
            "announced": ("not listened" if inp.listen_s <= 0 else "+".join(seen) if seen else "not announced"),
            "locked_params": result.locked,
            "notes": result.notes,
        }
        devices.append(dev)
        measures += [
            Measure(cfg.name, "camera_confirmed", 1.0, "", OK),
            Measure(cfg.name, "params_locked", float(len(result.locked)), "params", OK),
        ]
        lines.append(
            f"  {cfg.name}: {dev['model']} serial {dev['serial']} firmware {dev['firmware']}, "
            f"{len(result.locked)} parameters set and locked ({len(result.changed)} changed); "
            f"announced: {dev['announced']}"
        )
    backup = set_locked_params(source, locked)
    lines.append(f"  {source}: locked_params written (the previous file is {backup})")
    ctx.refresh()
    path = _json(ensure_dir(inp.out, "commissioning folder") / "devices.json", {"cameras": devices})
    return Outcome("cameras", StepCheck("cameras", measures, lines, {"cameras": devices}), True, artifacts=[path])


# ------------------------------------------------------------------ 2. trigger box


def trigger(ctx: Context) -> Outcome:
    """The trigger generator of rig.yaml asked who it is (`*IDN?`: serial and firmware version).
    Flashing the firmware is `vts trigger flash`, not a step of commissioning."""
    t = ctx.rig.trigger
    if t.backend == "none":
        raise ConfigError(
            "the rig config has no trigger generator (trigger: backend: none): the sync check needs "
            "one; set it, or --skip trigger --why TEXT"
        )
    with _trigger(ctx) as gen:
        ident = gen.identify() if hasattr(gen, "identify") else None
        st = gen.status()
    dev = {
        "backend": t.backend,
        "address": str(t.address),
        "device": st.device,
        "serial": getattr(ident, "serial", "?"),
        "firmware": getattr(ident, "firmware", "?"),
        "note": "firmware asked, not flashed (`vts trigger flash` uploads it)",
    }
    lines = [f"  {dev['device']}: serial {dev['serial']}, firmware {dev['firmware']} ({dev['note']})"]
    path = _json(ensure_dir(ctx.inputs.out, "commissioning folder") / "trigger.json", dev)
    return Outcome(
        "trigger",
        StepCheck("trigger", [Measure("trigger", "trigger_answered", 1.0, "", OK)], lines, {"trigger": dev}),
        True,
        artifacts=[path],
    )


# ------------------------------------------------------------------ 3. aim and focus


def aim(ctx: Context) -> Outcome:
    """procedures/aim.py's check of every camera (no drift baseline yet: the picture's margins);
    a camera to adjust stops the sequence with what to do."""
    folder = ensure_dir(ctx.inputs.out / "aim", "aim folder")
    measures, lines, advice, files, verdicts = [], [], [], [], {}
    with _cameras(ctx, ctx.rig.cameras) as cams:
        for cam in cams:
            report = aim_check(cam, ctx.rig)
            files.append(write_atomic(folder / f"{cam.name}-aim.png", report.overlay_png()))
            verdicts[cam.name] = report.to_dict()
            for v in report.items:
                st = TOL if v.state == "adjust" else OK
                if v.value is not None:
                    measures.append(Measure(cam.name, f"aim_{v.item}", float(v.value), v.unit, st))
                if v.state == "adjust":
                    advice.append(f"{cam.name} {v.label}: {v.text}")
            measures.append(
                Measure(
                    cam.name,
                    "aim_adjust",
                    float(sum(v.state == "adjust" for v in report.items)),
                    "items",
                    TOL if report.state == "adjust" else OK,
                )
            )
            unknown = f" (not known: {', '.join(report.unknown)})" if report.unknown else ""
            lines.append(f"  {cam.name}: {report.state.upper()}{unknown}")
    files.append(_json(folder / "aim.json", verdicts))
    lines += [f"  ADJUST {a}" for a in advice]
    passed = not advice
    return Outcome(
        "aim",
        StepCheck("aim", measures, lines, {"aim": verdicts}),
        passed,
        advice="; ".join(advice) + ("; then `vts commission --resume`" if advice else ""),
        artifacts=files,
    )


# ------------------------------------------------------------------ 4. warm-up


def _young(uptime: float | None, warmup_min: float) -> bool:
    """Whether a camera that has run ``uptime`` minutes (None: it does not tell) is still warming up."""
    return uptime is not None and uptime < warmup_min


def _upper(window, key: str) -> float:
    """A warm-up window's upper limit: its tolerance's, else its action's."""
    high = window.tolerance_high if window.tolerance_high is not None else window.action_high
    if high is None:
        raise ConfigError(f"tolerances: {key} has no upper limit (tolerance_high or action_high)")
    return high


def _uptime(cam, say) -> float | None:
    """Minutes the camera has run; None when it does not tell (a camera that does not answer
    is a device failure, raised)."""
    try:
        return cam.uptime().seconds / 60.0 if isinstance(cam, RunningTime) else None
    except NoUptime as exc:  # a camera that does not tell: not known, said
        say(f"  {cam.name}: uptime not known ({exc})")
        return None


def _minutes(m: float) -> str:
    return "a minute" if m < 1.5 else f"{m:.0f} min"


def _rate_text(fit) -> str:
    if fit.rate is None:
        return "rate not known (fewer than 3 samples with wall markers)"
    return f"{fit.rate:.3f} ± {fit.se:.3f} px/min over {fit.window_min:.1f} min"


def warmup(ctx: Context) -> Outcome:
    """Each camera's picture settled (procedures/warmup.py): the wall markers' mean position
    sampled every ``warmup.interval_s``, the rate fitted over the last ``warmup.samples``
    samples against the ``warmup_rate_px_min`` window, and its uptime against its warmup_min; its
    clock read at each sample, how fast its rate changes fitted over the same window against the
    ``warmup_clock_change_ppm_min`` window (procedures/warmup_clock.py). A camera not settled is
    waited for with progress (a line a sample), or (``wait`` False) the step stops saying how long:
    at once, before any sample, for a camera started less than its warmup_min ago (it cannot pass
    whatever its rate); after one window (``samples`` x ``interval_s``, needed to measure a rate)
    for the others."""
    st = ctx.rig.warmup
    windows = catalog.windows(ctx.rig.tolerances)
    window = windows["warmup_rate_px_min"]
    limit = _upper(window, "warmup_rate_px_min")
    cwin = windows["warmup_clock_change_ppm_min"]
    climit = _upper(cwin, "warmup_clock_change_ppm_min")
    warm = {c.name: float(c.warmup_min) for c in ctx.rig.cameras}
    with _cameras(ctx, ctx.rig.cameras, clock=ctx.clock) as cams:
        if not ctx.inputs.wait:  # no window measured for a camera that cannot have settled yet
            up = {c.name: _uptime(c, ctx.say) for c in cams}
            young = {n for n, m in up.items() if m is not None and m < warm[n]}
            if young:
                return _too_young(ctx, up, warm, young)
        ctx.say(
            f"  watching the wall markers settle: a sample every {st.interval_s:g} s, the rate fitted over "
            f"{st.samples} samples ({window.describe()}), each camera's clock read with it "
            f"({cwin.describe()} for its rate's change); Ctrl-C stops, `vts commission --resume` continues"
        )
        watches = {c.name: Watch(c, st.frames) for c in cams}
        clocks = {c.name: ClockWatch(c) for c in cams}
        for c in cams:
            switch_led(c, True)  # read back: a ring held off is said now, not as markers missing later
        ctx.sleep(LED_SETTLE_S)
        k = 0
        while True:
            k += 1
            for n, w in watches.items():
                w.sample()
                clocks[n].read()
            fits = {n: w.fit(st.samples) for n, w in watches.items()}
            cfits = {n: w.fits(st.samples) for n, w in clocks.items()}
            judged = {n: judge_clock(cfits[n][1], cwin, climit, clocks[n].problem) for n in clocks}
            now = "; ".join(f"{n} {'?' if f.rate is None else f'{f.rate:.3f}'} px/min" for n, f in fits.items())
            head = f"sample {k} of {st.samples}" if k <= st.samples else f"sample {k} (the last {st.samples})"
            clk = "; ".join(f"{n} {f[1].rate:.2f}" for n, f in cfits.items() if f[1].rate is not None)
            clk = f"; clock's change {clk} ppm/min" if clk else ""
            ctx.say(f"  {head}: rate now {now}{clk}" if k >= 3 else f"  {head}")
            if k < st.samples:
                ctx.sleep(st.interval_s)
                continue
            up = {c.name: _uptime(c, ctx.say) for c in cams}
            unsettled = {
                n
                for n, f in fits.items()  # an uptime not known: the rate alone tells
                if window.state(f.rate) != OK or _young(up[n], warm[n])
            }
            ticking = {n for n, j in judged.items() if j.known and not j.settled}  # a clock not known: said, not waited
            unknown = {n for n, f in fits.items() if f.rate is None}
            if not (unsettled | ticking) or not ctx.inputs.wait or unknown:
                break
            waits = {n: settle_wait_min(fits[n], limit, up[n], warm[n]) for n in sorted(unsettled)}
            cwaits = {
                n: settle_wait_min(cfits[n][1], climit, None, 0.0, "ppm/min", "its clock's change")
                for n in sorted(ticking)
            }
            ctx.say(
                "  not settled: "
                + "; ".join(
                    [
                        f"{n} ({_rate_text(fits[n])}): "
                        + (f"{'at least' if least else 'about'} {_minutes(m)} more" if m is not None else why)
                        for n, (m, why, least) in waits.items()
                    ]
                    + [
                        f"{n} {judged[n].why}: " + (f"about {_minutes(m)} more" if m is not None else why)
                        for n, (m, why, least) in cwaits.items()
                    ]
                )
                + "; waiting"
            )
            ctx.sleep(st.interval_s)
    measures, lines, data, advice, later = [], [], {}, [], []
    for n, f in fits.items():
        state = window.state(f.rate)
        uptime = up[n]
        warming = _young(uptime, warm[n])
        measures.append(Measure(n, "warmup_rate_px_min", None if f.rate is None else round(f.rate, 4), "px/min", state))
        measures.append(
            Measure(
                n,
                "uptime_min",
                None if uptime is None else round(uptime, 1),
                "min",
                TOL if uptime is None or warming else OK,
            )
        )
        if uptime is not None:
            measures.append(Measure(n, "warming_up", 1.0 if warming else 0.0, "", TOL if warming else OK))
        data[n] = {
            "rate_px_min": f.rate,
            "se_px_min": f.se,
            "window_min": f.window_min,
            "samples": f.n,
            "tau_min": f.tau_min,
            "uptime_min": up[n],
            "warmup_min": warm[n],
            "samples_taken": [(s.t, s.dx, s.dy, s.markers) for s in watches[n].samples],
        }
        cm, cadvice = _clock_figures(n, cfits[n], judged[n], cwin, climit, clocks[n], data[n], ctx.clock())
        measures += cm
        settled = n not in unsettled
        ran = (
            "uptime not known (the rate alone tells)"
            if up[n] is None
            else f"running {up[n]:.0f} min (warm-up {warm[n]:g} min)"
        )
        lines.append(
            f"  {n}: {_rate_text(f)} ({window.describe()}), {ran}: " + ("settled" if settled else "NOT settled")
        )
        lines.append(
            f"  {n}: {judged[n].why}"
            + (f" ({cwin.describe()})" if judged[n].known else "")
            + ": "
            + ("settled" if judged[n].settled else "NOT settled" if judged[n].known else "not known")
        )
        later += cadvice
        if settled:
            continue
        if f.rate is None:
            advice.append(
                f"{n}: no wall markers seen with the LED on: the rate is not known (check its LED ring and aim)"
            )
            continue
        m, why, least = settle_wait_min(f, limit, up[n], warm[n])
        data[n]["wait_min"], data[n]["wait_at_least"] = m, least
        until = "" if m is None else time.strftime("%H:%M", time.localtime(ctx.clock() + m * 60))
        advice.append(
            f"{n} not settled ({why or _rate_text(f)}): "
            + (
                f"wait {'at least' if least else 'about'} {_minutes(m)} (until {until})"
                if m is not None
                else "wait and run it again"
            )
        )
    advice += later  # the clocks' waits after the pictures'
    passed = not unsettled and not ticking
    tail = "; then `vts commission --resume`" if advice else ""
    return Outcome(
        "warmup", StepCheck("warmup", measures, lines, {"warmup": data}), passed, advice="; ".join(advice) + tail
    )


def _too_young(ctx: Context, up: dict, warm: dict, young: set) -> Outcome:
    """``--no-wait`` and a camera started less than its warmup_min ago: it cannot pass whatever its
    rate, so no window is measured; the step stops at once with how long to wait at least."""
    measures, lines, advice, data = [], [], [], {}
    for n, m in up.items():
        is_young = n in young
        measures += [
            Measure(n, "uptime_min", None if m is None else round(m, 1), "min", TOL if m is None or is_young else OK)
        ]
        if m is not None:
            measures.append(Measure(n, "warming_up", 1.0 if is_young else 0.0, "", TOL if is_young else OK))
        measures.append(Measure(n, "warmup_rate_px_min", None, "px/min", TOL))
        data[n] = {"uptime_min": m, "warmup_min": warm[n], "rate_px_min": None}
        ran = "uptime not known" if m is None else f"running {m:.0f} min (warm-up {warm[n]:g} min)"
        lines.append(
            f"  {n}: {ran}"
            + (": NOT settled (the rate is not measured before its warm-up time is up)" if is_young else "")
        )
        if is_young:
            left = warm[n] - m
            until = time.strftime("%H:%M", time.localtime(ctx.clock() + left * 60))
            data[n]["wait_min"], data[n]["wait_at_least"] = left, True
            advice.append(
                f"{n} started {m:.0f} min ago, less than its {warm[n]:g} min warm-up time: wait at least "
                f"{_minutes(left)} (until {until}), its picture's rate is measured then"
            )
    return Outcome(
        "warmup",
        StepCheck("warmup", measures, lines, {"warmup": data, "measured": False}),
        False,
        advice="; ".join(advice) + "; then `vts commission --resume`",
    )


def _clock_figures(n, cfit, judged, cwin, climit, watch, data, now):
    """The clock's measures, stored figures and advice for camera ``n`` (procedures/warmup_clock.py)."""
    rate, change, signed = cfit
    measures = [
        Measure(
            n, "warmup_clock_change_ppm_min", round(change.rate, 3) if judged.known else None, "ppm/min", judged.state
        ),
        Measure(
            n,
            "warmup_clock_rate_ppm",
            None if signed is None else round(signed, 2),
            "ppm",
            OK if rate.rate is not None else TOL,
        ),
    ]
    data["clock"] = {
        "change_ppm_min": change.rate,
        "change_se_ppm_min": change.se,
        "known": judged.known,
        "state": str(judged.state.value),
        "why": judged.why,
        "window": cwin.describe(),
        "rate_ppm": signed,
        "rate_se_ppm": rate.se,
        "tau_min": change.tau_min,
        "window_min": change.window_min,
        "samples": change.n,
        "readings": [(r.t, r.offset_s, r.uncertainty_s, r.method) for r in watch.readings],
    }
    if not judged.known or judged.settled:
        return measures, []
    m, why, _ = settle_wait_min(change, climit, None, 0.0, "ppm/min", "its clock's change")
    data["clock"]["wait_min"] = m
    until = "" if m is None else time.strftime("%H:%M", time.localtime(now + m * 60))
    return measures, [
        f"{n}'s clock not settled ({why}): "
        + (f"wait about {_minutes(m)} (until {until})" if m is not None else "wait and run it again")
    ]


# ------------------------------------------------------------------ rig.yaml's calibration paths


def _point_rig(ctx: Context, step: str, key: str, file: Path, what: str) -> tuple[str, Exception | None]:
    """rig.yaml's ``calibration.KEY`` set to ``file`` (the step passed and saved it), as `vts camera
    setup` writes locked_params (vts_hw.rig_file.set_calibration): the note for the report, and
    the error when rig.yaml could not be written (one sentence; ``file`` is kept; the step is then
    recorded as not passed and raised; `vts commission --from STEP` runs it again)."""
    source = getattr(ctx.rig, "_source", None)
    if source is None:
        return "the rig config was not read from a file: no rig.yaml to point at it", None
    old, name = getattr(ctx.rig.calibration, key, None), Path(source).name
    try:
        backup = set_calibration(source, {key: file})
    except WriteFailed as exc:
        err = WriteFailed(
            exc.path,
            exc.reason,
            f"{source} is unchanged (calibration.{key}: {old or 'none'}); the new "
            f"{what} is kept in {file}: `vts commission --from {step}` once {source} can be written",
        )
        return f"{name} not changed: it could not be written", err
    except VtsError as exc:  # changed by someone else meanwhile; a file that no longer loads
        return f"{name} not changed", type(exc)(f"{exc} (the new {what} is kept in {file})")
    if backup is None:
        note = f"{name} already points at {file} (calibration.{key})"
    else:
        note = f"{name} now points at {file} (calibration.{key}; the previous text is in {backup})"
        ctx.refresh()
    ctx.say(f"  {note}")
    return note, None


# ------------------------------------------------------------------ 5. calibration


def calibration(ctx: Context) -> Outcome:
    """`vts calibrate cameras IMAGES`' procedure on the checkerboard images given."""
    inp = ctx.inputs
    if not inp.checkerboards:
        raise _need(
            "calibration",
            "--checkerboards DIR",
            "checkerboard images of every camera (DIR/cam1/01.png, "
            "... or cam1_01.png; each view seen by two cameras or more, 15-20 poses over the field of view)",
        )
    ensure_dir(inp.out, "commissioning folder")
    run = calibration_procedure.run(
        images=calibration_procedure.camera_images(list(inp.checkerboards)),
        output=str(inp.calibration_file),
        pattern=inp.pattern,
        square=inp.square_mm,
        unit="mm",
        previous=None,
    )
    run.tolerances = ctx.rig.tolerances
    ctx.say(run.results())
    if run.saved.error is not None:
        raise run.saved.error
    refused = getattr(run, "refused", None)
    passed = not refused and run.state != ACT
    advice = refused or ("calibrate again: " + "; ".join(run.warnings) if not passed else "")
    notes, error = f"saved to {inp.calibration_file}", None
    if passed and run.saved.written is not None:  # only a calibration that passed is pointed at
        note, error = _point_rig(ctx, "calibration", "cameras", run.saved.written, "calibration")
        notes, passed, advice = f"{notes}; {note}", error is None, str(error) if error else advice
    return Outcome("calibration", run, passed, advice=advice, notes=notes, error=error)


# ------------------------------------------------------------------ 6. mapping


def mapping(ctx: Context) -> Outcome:
    """`vts calibrate spect --from-cameras --volume FILE`: the phantom's spheres seen now by the
    calibrated cameras against the SPECT's reconstruction of it."""
    inp = ctx.inputs
    if not inp.phantom_volume:
        raise _need(
            "VTS → SPECT mapping",
            "--phantom-volume FILE",
            "the SPECT's reconstruction of the 7-sphere phantom lying where the cameras see it now",
        )
    calib = camera_calibration_for(ctx.rig, str(inp.calibration_file), "the mapping")
    with _cameras(ctx, calibrated_cameras(ctx.rig, calib)) as cams:
        m = mapping_from_cameras(cams, calib, inp.phantom_volume, inp.frames, progress=lambda t: ctx.say(f"  {t}"))
    m.tolerances = ctx.rig.tolerances
    saved = save_or_keep(inp.mapping_file, json.dumps(m.transform.to_dict(), indent=2) + "\n", "mapping")
    if saved.error is not None:
        raise saved.error
    ctx.say(m.results())
    passed = m.state != ACT
    advice = (
        ""
        if passed
        else ("the mapping is in ACTION: check the phantom and its volume, then `vts commission --from mapping`")
    )
    notes, error = f"saved to {inp.mapping_file}", None
    if passed:  # a mapping in ACTION leaves calibration.mapping as it was
        if saved.written is None:  # a Saved without its file has its error, raised above
            raise RuntimeError(f"{inp.mapping_file}: not written")
        note, error = _point_rig(ctx, "mapping", "mapping", saved.written, "VTS → SPECT mapping")
        notes, passed, advice = f"{notes}; {note}", error is None, str(error) if error else advice
    return Outcome("mapping", m, passed, advice=advice, notes=notes, error=error)


# ------------------------------------------------------------------ 7. step test


def steps(ctx: Context) -> Outcome:
    """`vts qa steps --volumes DIR`: the operator moves the table when asked."""
    inp = ctx.inputs
    if not inp.step_volumes:
        raise _need(
            "step test",
            "--step-volumes DIR",
            "the folder the SPECT's reconstructions of the positions "
            "(baseline, V01 ..., A01 ..., free) are or will be exported to",
        )
    inputs = step_test_inputs(ctx.rig, str(inp.calibration_file), str(inp.mapping_file), inp.step_volumes)
    with _cameras(ctx, calibrated_cameras(ctx.rig, inputs.calibration)) as cams:
        res = run_step_test(
            ctx.rig,
            inputs,
            inp.out / "steps",
            step_plan(inp.vertical, inp.axial),
            cameras=cams,
            frames=inp.frames,
            ask=ctx.ask,
            progress=lambda t: ctx.say(f"  {t}"),
        )
    ctx.say(res.analysis.results())
    if res.plot_error is not None:
        raise res.plot_error
    return Outcome(
        "steps",
        res.analysis,
        res.analysis.state != ACT,
        started=res.started,
        artifacts=res.artifacts,
        advice="the step test is in ACTION: see its figures; `vts commission --from steps` after the fix",
    )


# ------------------------------------------------------------------ 8. sync check


def sync(ctx: Context) -> Outcome:
    """`vts sync analyze SESSION --listmode FILE` on a scan recorded during a SPECT acquisition."""
    inp = ctx.inputs
    if not inp.sync_session or not inp.listmode:
        raise _need(
            "sync check",
            "--sync-session DIR and --listmode FILE",
            "record a scan with a source marker moved a few times along the table during a SPECT list-mode "
            "acquisition (`vts scan start --duration 30 -o DIR`)",
        )
    check_session(inp.sync_session)
    a = SyncAnalysis(inp.sync_session, list(inp.listmode), inp.calibration_file, inp.mapping_file)
    a.analyze(tolerances=ctx.rig.tolerances)
    ctx.say(a.results())
    return Outcome(
        "sync",
        a,
        a.state != ACT,
        notes=f"session {inp.sync_session}",
        advice="the sync check is in ACTION: see its events; record another scan and "
        "`vts commission --from sync` with it",
    )


# ------------------------------------------------------------------ 9. drift baseline


def baseline(ctx: Context) -> Outcome:
    """`vts qa drift --set-baseline`: the wall markers of every camera, the room clear."""
    if ctx.inputs.room_clear:
        ctx.say("  the room is clear (--room-clear): the wall markers are taken now")
    else:
        ctx.ask("Clear the table and the room (phantom and source marker away), LED rings on. Press Enter.")
    with _cameras(ctx, ctx.rig.cameras, clock=ctx.clock) as cams:
        result = take_baselines(cams, frames=5, clock=ctx.clock)
    ctx.say(result.results())
    return Outcome("baseline", result, True)


__all__ = ["cameras", "trigger", "aim", "warmup", "calibration", "mapping", "steps", "sync", "baseline"]
