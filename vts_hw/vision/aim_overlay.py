"""The aim-and-focus picture: the camera's LED-on picture with what the check saw drawn on it.

Drawn (BGR, anti-aliased): the margin every marker should keep (grey frame) and the picture's
centre (grey cross); each marker, circled green when its edge is within the focus goal, orange
when not, red when cut by the border, with its edge width; with a mapping, the SPECT FOV
(green), the gantry's opening (cyan) and the table top (orange) where the calibration and the
mapping put them; a legend and each item's verdict in the corner. PNG bytes, from OpenCV.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["overlay_png", "overlay_image", "COLOURS"]

COLOURS = {
    "fov": (60, 200, 60),
    "gantry": (230, 200, 40),
    "table": (40, 150, 255),
    "sharp": (60, 220, 60),
    "blurred": (0, 165, 255),
    "cut": (40, 40, 230),
    "guide": (140, 140, 140),
    "good": (60, 220, 60),
    "adjust": (0, 165, 255),
    "unknown": (170, 170, 170),
}
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _text(img, text, org, colour, scale=0.4) -> None:
    cv2.putText(img, text, org, _FONT, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, org, _FONT, scale, colour, 1, cv2.LINE_AA)


def _lines(img, outline, colour) -> None:
    for line in outline.lines:
        pts = np.round(line * 16).astype(np.int32).reshape(-1, 1, 2)  # 4 fractional bits
        cv2.polylines(img, [pts], False, colour, 1, cv2.LINE_AA, shift=4)


def overlay_image(report) -> np.ndarray:
    """The overlay as a BGR image (see the module docstring)."""
    w, h = report.size
    base = report.image if report.image is not None else np.zeros((h, w), np.uint8)
    img = cv2.cvtColor(base, cv2.COLOR_GRAY2BGR)
    margin = int(round(report.settings.edge_margin_px))
    guide = COLOURS["guide"]
    if margin > 0:
        cv2.rectangle(img, (margin, margin), (w - 1 - margin, h - 1 - margin), guide, 1, cv2.LINE_AA)
    cx, cy = w // 2, h // 2
    cv2.line(img, (cx - 8, cy), (cx + 8, cy), guide, 1, cv2.LINE_AA)
    cv2.line(img, (cx, cy - 8), (cx, cy + 8), guide, 1, cv2.LINE_AA)
    if report.view is not None:
        view = report.view
        _lines(img, view.table(), COLOURS["table"])
        _lines(img, view.bore(), COLOURS["gantry"])
        _lines(img, view.fov(), COLOURS["fov"])
        uv, front = view.project(view.centre)
        if front[0]:
            p = tuple(int(round(v)) for v in uv[0])
            cv2.drawMarker(img, p, COLOURS["fov"], cv2.MARKER_CROSS, 14, 1, cv2.LINE_AA)
    limit = report.settings.edge_width_max_px
    for m in report.markers:
        p = (int(round(m.x)), int(round(m.y)))
        r = int(round((m.diameter_px or 8.0) / 2 + 4))
        if m.cut:
            colour = COLOURS["cut"]
        else:
            colour = (
                COLOURS["sharp"] if m.edge_width_px is not None and m.edge_width_px <= limit else COLOURS["blurred"]
            )
        cv2.circle(img, p, r, colour, 1, cv2.LINE_AA)
        if m.edge_width_px is not None:
            _text(img, f"{m.edge_width_px:.1f}", (p[0] + r + 2, p[1] + 4), colour, 0.35)
    y = 14
    _text(img, f"{report.camera}: {report.state.upper()}", (6, y), COLOURS[report.state], 0.45)
    for v in report.items:
        y += 13
        _text(img, f"{v.label}: {v.state}", (6, y), COLOURS[v.state], 0.35)
    if report.view is not None:
        x = 6
        for name, key in (("FOV", "fov"), ("gantry opening", "gantry"), ("table", "table")):
            _text(img, name, (x, h - 8), COLOURS[key], 0.4)
            x += 12 + 8 * len(name)
    return img


def overlay_png(report) -> bytes:
    """The overlay as PNG bytes."""
    ok, buf = cv2.imencode(".png", overlay_image(report))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()
