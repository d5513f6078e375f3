"""The printed table and the verdicts of bench/motion_under_loss.py, counted from the rows."""

from __future__ import annotations

from losskit.truth import POSE_GOAL, RATE_GOAL, START_GOAL

GOAL_LOSS = 20.0  # %: up to this loss every figure must meet its goal
AGREE_GOAL = (0.1, 0.05)  # mm, deg RMS: the live poses against the offline ones of the same model (issue 33)


def header(a, cores: int, load) -> str:
    return (
        f"motion under loss: simulated patient scans through the real path -- the simulated Axis cameras over "
        f"HTTP on 127.0.0.1 with their declared burst-loss fault, frames made ahead of time (not a replay), "
        f"`vts scan start` live (reference {10:g} s), then `vts motion analyze --export`; seeds "
        f"{' '.join(map(str, a.seeds))}, {' and '.join(map(str, a.cameras))} cameras (the scans of one loss "
        f"share run at the same time), {a.seconds:g} s each, loss {', '.join(f'{x:g}' for x in a.losses)} % in "
        f"~1 s bursts"
        + (
            ""
            if a.no_load
            else f", and {a.load_loss:g} % under a CPU load of {a.per_core} spinning process(es) per core"
        )
        + f"; {cores} cores, load average "
        f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} at the start"
    )


def _case(r) -> str:
    return f"s{r['seed']} {r['cameras']}cam {r['loss']:g}%" + (" LOAD" if r["load"] else "")


def _rate(o) -> str:
    x = o["rate"]
    if x["status"] == "measured":
        return f"{x['rate']:.2f} ({x['err']:+.2f})"
    if x["status"] == "bounded":
        return f"bounded [{x['range'][0]:.1f}, {x['range'][1]:.1f}] truth {'in' if x['inside'] else 'OUT'}"
    return x["status"]


def _moves(o) -> str:
    m = o["moves"]
    s = f"{m['found']}" + (f"+{m['bounded']}b" if m["bounded"] else "") + f"/{m['moves'] - m['unseen']}"
    if m["unseen"]:
        s += f" ({m['unseen']} after the last pose)"
    if m["max_err"] is not None:
        s += f" {m['max_err']:+.2f} s"
    if m["ranges"]:
        s += " b " + ", ".join(f"[{lo:+.1f},{hi:+.1f}]" for lo, hi in m["ranges"])
    if m["false"]:
        s += f" {m['false']} false"
    return s


def _alerts(lv) -> str:
    if not lv["latency"]:
        return "-"
    got = [d for k, d in lv["latency"] if d is not None]
    b = sum(1 for k, _ in lv["latency"] if k == "bounded")
    none = sum(1 for k, _ in lv["latency"] if k == "none")
    s = f"{max(got):.2f} ({len(got)}/{len(lv['latency'])})" if got else f"- (0/{len(lv['latency'])})"
    s += f" {b}b" if b else ""
    return s + (f" {none} none" if none else "") + (f" +{lv['other_alerts']} other" if lv["other_alerts"] else "")


def _agree(a) -> str:
    """The live poses against the offline ones (the analysis' ``live``), and the alerts explained."""
    if not a or not a.get("compared"):
        return "-" if not a else f"none compared of {a['live_poses']}"
    al = a.get("alerts") or []
    return (
        f"{a['rms_mm']:.3f} ({a['worst_mm']:.3f}) / {a['rms_deg']:.4f} ({a['worst_deg']:.4f}); "
        f"{sum(x['explained'] for x in al)}/{len(al)}"
    )


def row_line(r) -> list[str]:
    if r is None:
        return [
            "| case | lost % (+extra) | covered: reported / true | breathing /min (error) | truth | pose RMS mm / deg "
            "| moves found/true, max start error | alert s after start (max) | NOT TRACKING s: reported / truly "
            "(unreported); of it frames too late | live vs offline pose RMS (worst) mm / deg; alerts explained "
            "| unknown/ bounded | not flagged | scan + analysis s |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
    lv, o = r["live"], r["offline"]
    lost = f"{100 * r['dropped']:.1f} (+{r['extra']})" + (f" {r['bank_live']} live" if r["bank_live"] else "")
    nt = (
        "-"
        if lv["reported"] is None
        else f"{lv['reported']:.2f} / {lv['truly']:.2f} ({lv['unreported']:.2f})"
        + (f"; {lv['late']:.1f} late" if lv["late"] >= 0.05 else "")
    )
    if o is None:
        off = ["analysis failed", "-", "-", "-"]
    else:
        off = [
            f"{100 * o['covered']:.1f} / {100 * o['true_covered']:.1f} %",
            _rate(o),
            f"{o['rate']['truth']:.2f}",
            f"{o['pose'][0]:.3f} / {o['pose'][1]:.3f}",
        ]
    line = (
        f"| {_case(r)} | {lost} | {off[0]} | {off[1]} | {off[2]} | {off[3]} | "
        f"{'-' if o is None else _moves(o)} | {_alerts(lv)} | {nt} | {_agree(r.get('agree'))} | {r['flagged']} | "
        f"{len(r['bad'])} | "
        f"{r['wall_s']:.0f} + {r['analysis_s']:.0f} |"
    )
    return [line] + [f"|   ^ not flagged: {b} |" for b in r["bad"]]


def verdicts(rows) -> tuple[list[str], bool]:
    """One line per goal: met, or missed in N cases (which); and whether any figure outside its
    goal was not flagged or any blind time went unreported (the bench's exit status)."""
    upto = [r for r in rows if r["loss"] <= GOAL_LOSS]
    lines = []

    def line(text, cases, missed):
        which = ", ".join(_case(r) for r in missed)
        lines.append(
            f"{text}: "
            + ("goal met" if not missed else f"goal missed in {len(missed)} of {len(cases)} cases ({which})")
            + f" [{len(cases)} cases]"
        )

    def rate_ok(r):
        x = (r["offline"] or {}).get("rate")
        return x is not None and x["status"] == "measured" and abs(x["err"]) <= RATE_GOAL

    def pose_ok(r):
        o = r["offline"]
        return o is not None and o["pose"][0] <= POSE_GOAL[0] and o["pose"][1] <= POSE_GOAL[1]

    def moves_ok(r):
        m = (r["offline"] or {}).get("moves")
        return m is not None and m["found"] == m["moves"] and not m["false"]

    def alert_ok(r):
        lv = r["live"]
        return (
            lv["reported"] is not None
            and not lv["other_alerts"]
            and all(k == "measured" and d <= lv["after"] + 0.5 for k, d in lv["latency"])
        )

    line(
        f"up to {GOAL_LOSS:g} % lost: breathing rate measured within ±{RATE_GOAL} /min",
        upto,
        [r for r in upto if not rate_ok(r)],
    )
    line(
        f"up to {GOAL_LOSS:g} % lost: body pose <= {POSE_GOAL[0]} mm / {POSE_GOAL[1]} deg RMS",
        upto,
        [r for r in upto if not pose_ok(r)],
    )
    line(
        f"up to {GOAL_LOSS:g} % lost: every move >= 2 mm found, start within {START_GOAL} s, no false event",
        upto,
        [r for r in upto if not moves_ok(r)],
    )
    line(
        f"up to {GOAL_LOSS:g} % lost: every move alerted <= alert_after_s + 0.5 s after its start, no other alert",
        upto,
        [r for r in upto if not alert_ok(r)],
    )

    def agree_ok(r):
        a = r.get("agree")
        return bool(
            a
            and a.get("compared")
            and a["rms_mm"] <= AGREE_GOAL[0]
            and a["rms_deg"] <= AGREE_GOAL[1]
            and all(x["explained"] for x in a.get("alerts") or [])
        )

    line(
        f"up to {GOAL_LOSS:g} % lost: live and offline poses agree <= {AGREE_GOAL[0]} mm / {AGREE_GOAL[1]} deg RMS, "
        f"every live alert explained offline",
        upto,
        [r for r in upto if not agree_ok(r)],
    )
    line(
        "any loss: no figure outside its goal that is not flagged unknown or bounded",
        rows,
        [r for r in rows if r["bad"]],
    )
    line(
        "any loss: no blind time unreported (each stretch > 0.5 s without frames NOT TRACKING in the manifest)",
        rows,
        [r for r in rows if r["live"]["unreported"] is None or any("not reported" in b for b in r["live"]["bad"])],
    )
    return lines, any(r["bad"] for r in rows)
