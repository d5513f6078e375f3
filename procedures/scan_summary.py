"""What a scan session's manifest says, in the words `vts scan start` prints at the end: the
status (complete / partial / failed) and why, each camera's frames and gaps, the trigger, the
live motion path, and the verdict (what the command's exit status says). The room console's
Scan page shows the same lines, so that the two never tell a scan differently."""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

__all__ = ["summary_lines", "live_summary", "verdict", "fmt_time"]


def fmt_time(t: float | None) -> str:
    if t is None:
        return "-"
    return _dt.datetime.fromtimestamp(t, _dt.UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-4] + "Z"


def summary_lines(folder: Path, m: dict) -> list[str]:
    """The end-of-scan summary of the manifest ``m`` of ``folder`` (one string a line)."""
    if not m:
        return [f"{folder}: nothing recorded"]
    scan = m.get("scan", {})
    out = [f"{folder}: status {m['status']} (stopped: {scan.get('stop_reason')})"]
    for name, c in m["cameras"].items():
        before = (c.get("clock_offset_before") or {}).get("offset_s")
        after = (c.get("clock_offset_after") or {}).get("offset_s")
        clock = f", clock {before:+.3f} s -> {after:+.3f} s" if before is not None and after is not None else ""
        out.append(
            f"  {name}: {c['frames']} frames, {c['dropped_frames']} dropped in {len(c['gaps'])} gap(s), "
            f"{c.get('reconnects', 0)} reconnect(s){clock}"
        )
    tr = m.get("trigger", {})
    if tr.get("backend") == "none":
        out.append("  trigger: none (recording only)")
    else:
        fired = f"fired at {fmt_time(tr.get('fire_time'))} ({tr.get('mode')})" if tr.get("fired") else "NOT fired"
        edges = f", {tr['edges']} rising edge(s)" if tr.get("edges") is not None else ""
        out.append(f"  trigger: {tr.get('backend')} {fired}{edges}; log {folder / 'trigger.csv'}")
        for key in ("note", "no_watchdog"):
            if tr.get(key):
                out.append(f"  note: {tr[key]}")
    lm = m.get("live_motion") or {}
    if lm:
        out.append(f"  live motion: {live_summary(lm)}")
    for p in scan.get("problems", []):
        out.append(f"  problem: {p}")
    if scan.get("live_problem"):
        out.append(f"  problem: {scan['live_problem']}")
    return out


def live_summary(lm: dict) -> str:
    if lm.get("status") == "off":
        return f"off ({lm.get('off_reason', '')})"
    s = lm.get("summary") or {}
    tr = s.get("tracking") or {}
    parts = [
        f"TRACKING {tr.get('tracking_s', 0):.1f} s, REFERENCE {tr.get('reference_s', 0):.1f} s, "
        f"NOT TRACKING {tr.get('not_tracking_s', 0):.1f} s in {tr.get('not_tracking_stretches', 0)} stretch(es)"
        + (
            f" (longest {tr['longest_not_tracking_s']:.1f} s: {tr.get('longest_reason', '')})"
            if tr.get("longest_not_tracking_s")
            else ""
        )
    ]
    parts.append(
        f"{len(lm.get('alerts', []))} motion alert(s), {len(lm.get('blind_alerts', []))} NOT TRACKING alert(s)"
    )
    dropped = sum((s.get("live_dropped") or {}).values())
    parts.append(f"{dropped} frame(s) dropped from the live path (never from the recording)")
    if s.get("error"):
        parts.append(s["error"])
    return "; ".join(parts)


def verdict(folder: Path, m: dict | None, write_failure=None) -> tuple[str, int]:
    """(the last word, the exit status of `vts scan start`): 0 and "" when the session is
    complete and the patient was watched; else the sentence it prints and its status."""
    if write_failure is not None:
        return str(write_failure), write_failure.exit_code
    if m and m.get("status") != "complete":
        return f"the session in {folder} is {m.get('status')}: see the problems above", 4
    problem = (m or {}).get("scan", {}).get("live_problem")
    if problem:
        return f"the session in {folder} recorded every camera, but {problem}", 4
    return "", 0
