"""The calibration report as text: the one renderer of every calibration run (`vts calibrate
stereo` and `vts calibrate cameras`).

:func:`run_text` prints the record (:meth:`~vts_hw.vision.calibration_io.CameraCalibration.results`),
the view graph, the errors against a simulated truth and the change from the previous
calibration, each as the run measured it: a pair whose intrinsics come from OpenCV alone (the
stereo case) is judged as a pair (the turn and move of camera 2 from camera 1 against their
covariance, decision 0024), N cameras camera by camera (decision 0030); then what was written
and the warnings.
"""

from __future__ import annotations

from typing import Any

from vts_hw.vision.calibration_uncertainty import K_SIGMA


def run_text(run) -> str:
    """The whole report of a :class:`vts_hw.procedures.calibration.CalibrationRun`."""
    g = run.calib.view_graph
    lines = [run.calib.results()]
    if g:
        lines.append("View graph: " + ("connected" if g.get("connected") else "NOT connected"))
        for cam, views in g.get("cameras", {}).items():
            lines.append(f"  {cam}: {', '.join(views)}")
        lines += [
            f"  {e['cameras'][0]} - {e['cameras'][1]}: {e['shared_views']} shared view(s)" for e in g.get("edges", [])
        ]
    if run.truth is not None:
        lines.append(truth_text(run.truth))
    if run.change is not None:
        lines.append(change_text(run.change, run.previous_path))
    if run.saved.written:
        lines.append(f"wrote {run.saved.written}")
    lines += [f"  {w}" for w in run.untrusted]
    if run.refused:
        lines.append(f"NOT SAVED: {run.refused}")
    elif run.untrusted:
        lines.append(f"{len(run.warnings)} warning(s); the fit cannot be trusted but --force wrote it.")
    elif run.warnings:
        lines.append(
            f"{len(run.warnings)} warning(s) above; the calibration was still saved"
            " (a warning does not fail the run: exit code 0)."
        )
    return "\n".join(lines)


def truth_text(truth: dict[str, Any]) -> str:
    """The errors against the simulated truth: N cameras' (with the 3D error over the field of
    view), or a pair's."""
    return _cameras_truth_text(truth) if "points_3d" in truth else _pair_truth_text(truth)


def change_text(change: dict[str, Any], prev_path) -> str:
    """The change from the previous calibration: camera by camera, or as a pair."""
    return _cameras_change_text(change, prev_path) if "cameras" in change else _pair_change_text(change, prev_path)


def _pm(sd, fmt: str = ".2g") -> str:
    return f" ± {sd:{fmt}}" if sd is not None else ""


def _pair_truth_text(truth: dict[str, Any]) -> str:
    """The errors of a pair against the simulated truth, each with the fit's standard deviation."""
    lines = ["Compared with the simulated truth (estimated - true ± the fit's standard deviation):"]
    for name, rows in truth["cameras"].items():
        fx, fy, cx, cy, k1 = (rows[k] for k in ("fx", "fy", "cx", "cy", "k1"))
        lines.append(
            f"  {name}: fx {fx['error']:+.2f}{_pm(fx['sd'], '.2g')} px ({fx['error_percent']:+.3f} %),"
            f" fy {fy['error']:+.2f}{_pm(fy['sd'], '.2g')} px ({fy['error_percent']:+.3f} %),"
            f" cx {cx['error']:+.2f}{_pm(cx['sd'], '.2g')} px, cy {cy['error']:+.2f}{_pm(cy['sd'], '.2g')} px,"
            f" k1 {k1['estimated']:+.4f} vs {k1['true']:+.4f} ({k1['error']:+.4f}{_pm(k1['sd'], '.2g')})"
        )
    rot, base = truth["rotation"], truth["baseline"]
    lines.append(
        f"  stereo rotation {rot['estimated_deg']:.4f} deg vs {rot['true_deg']:.4f} deg:"
        f" off by {rot['error_deg']:.4f}{_pm(rot['sd_deg'], '.2g')} deg"
    )
    lines.append(
        f"  baseline {base['estimated']:.2f} vs {base['true']:.2f} {base['unit']}:"
        f" {base['error']:+.2f}{_pm(base['sd'], '.2g')} {base['unit']} ({base['error_percent']:+.3f} %),"
        f" direction off by {base['direction_error_deg']:.4f} deg"
    )
    lines += [f"  {w}" for w in truth["warnings"]] or [
        f"  every fitted parameter is within {K_SIGMA:g} standard deviations of the truth"
    ]
    return "\n".join(lines)


def _pair_change_text(change: dict[str, Any], prev_path) -> str:
    """The change of a pair from the previous calibration, judged against the combined uncertainty."""
    unit = change["unit"]
    sds = {r["parameter"]: r["sd"] for r in change.get("judged", [])}
    lines = [
        f"Change from the previous calibration {prev_path}" + (" (± combined standard deviation):" if sds else ":")
    ]
    for cam in ("1", "2"):
        parts = [f"{k} {change[k + cam]:+.2f}{_pm(sds.get(k + cam), '.2g')}" for k in ("fx", "fy", "cx", "cy")]
        lines.append(f"  camera {cam}: {' '.join(parts)} px")
    text = f"  rotation between cameras changed by {change['rotation_deg']:.4f}{_pm(sds.get('rotation'), '.2g')} deg"
    if unit is None:
        text += "; translation not compared (different units)"
    else:
        text += (
            f", translation by {change['translation']:.4g}{_pm(sds.get('translation'), '.2g')} {unit},"
            f" baseline {change['baseline']:+.4g} {unit}"
        )
    lines.append(text)
    if sds and not change.get("previous_has_uncertainty", True):
        lines.append("  (the previous file has no uncertainties: taken as equal to this one's)")
    if sds:
        lines += [f"  {w}" for w in change["warnings"]] or [
            f"  every change is within {K_SIGMA:g} combined standard deviations"
        ]
    return "\n".join(lines)


def _cameras_truth_text(truth: dict[str, Any]) -> str:
    p = truth["points_3d"]
    lines = ["Compared with the simulated truth (estimated - true ± the fit's standard deviation):"]
    for name, rows in truth["cameras"].items():
        lines.append(
            f"  {name}: "
            + ", ".join(
                f"{k} {rows[k]['error']:+.{4 if k == 'k1' else 2}f}{_pm(rows[k]['sd'])}"
                for k in ("fx", "fy", "cx", "cy", "k1")
            )
            + f"; turned {rows['rotation_error_deg']:.4f} deg, moved {rows['position_error']:.2f}"
            f" {p['unit']}"
        )
    if p["rms"] is not None:
        lines.append(
            f"  3D error of {p['n']} points over the field of view: RMS {p['rms']:.3f} {p['unit']},"
            f" max {p['max']:.3f} {p['unit']}; after the best rigid fit RMS"
            f" {p['rms_after_rigid_fit']:.4f} {p['unit']}"
        )
    lines += [f"  {w}" for w in truth["warnings"]] or [
        f"  every fitted intrinsic is within {K_SIGMA:g} standard deviations of the truth"
    ]
    return "\n".join(lines)


def _cameras_change_text(change: dict[str, Any], prev_path) -> str:
    unit = change["unit"]
    lines = [f"Change from the previous calibration {prev_path} (cameras matched by {change['matched_by']}):"]
    for name, row in change["cameras"].items():
        pos = (
            f", moved {row['position']:.4g} {unit}"
            if row["position"] is not None
            else "; position not compared (different units)"
        )
        lines.append(
            f"  {name}: fx {row['fx']:+.2f} fy {row['fy']:+.2f} cx {row['cx']:+.2f} cy {row['cy']:+.2f} px,"
            f" k1 {row['k1']:+.4f}; turned {row['rotation_deg']:.4f} deg{pos}"
        )
    if change["judged"]:
        lines += [f"  {w}" for w in change["warnings"]] or [
            f"  every change is within {K_SIGMA:g} combined standard deviations"
        ]
    return "\n".join(lines)
