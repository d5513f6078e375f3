"""The verdict of each item of the aim-and-focus check: good, adjust (and how), or unknown (and why).

Each function takes what vts_hw/vision/aim.py measured and the goals
(:class:`~vts_hw.vision.aim_settings.AimSettings`) and returns one :class:`Verdict` whose
``text`` a person reads at the camera: what to do, the figure, the goal. Directions are the
camera's: "aim 2° left" turns the camera to its left (the picture's content moves right).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vts_hw.vision.aim_settings import AimSettings

__all__ = [
    "Verdict",
    "GOOD",
    "ADJUST",
    "UNKNOWN",
    "picture_shift",
    "marker_verdicts",
    "level_verdicts",
    "aim_verdict",
    "fov_verdict",
    "gantry_verdict",
]

GOOD, ADJUST, UNKNOWN = "good", "adjust", "unknown"


@dataclass(frozen=True)
class Verdict:
    """One item: ``state`` good / adjust / unknown; ``value`` in ``unit`` (None: not measured);
    ``goal`` in words; ``text`` what to do (or why not known); ``turn``: for aim items, the
    turn advised, ``{"right_deg", "up_deg"}`` (negative: left, down)."""

    item: str
    label: str
    state: str
    value: float | None
    unit: str
    goal: str
    text: str
    turn: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        v = self.value
        return {
            "item": self.item,
            "label": self.label,
            "state": self.state,
            "value": None if v is None or not math.isfinite(v) else round(float(v), 3),
            "unit": self.unit,
            "goal": self.goal,
            "text": self.text,
            "turn": dict(self.turn),
        }


def _unknown(item, label, unit, goal, why) -> Verdict:
    return Verdict(item, label, UNKNOWN, None, unit, goal, f"not known: {why}")


def _median(values) -> float | None:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.median(vals)) if vals else None


def marker_verdicts(markers, s: AimSettings) -> list[Verdict]:
    """Focus (edge width, and against the radius) and size of the whole markers."""
    goal_f = f"≤ {s.edge_width_max_px:g} px, ≤ {s.edge_ratio_max:g} of the radius"
    goal_s = f"{s.marker_diameter_min_px:g}-{s.marker_diameter_max_px:g} px across"
    if not markers:
        return [
            _unknown("focus", "focus", "px", goal_f, "no marker in the picture"),
            _unknown("size", "marker size", "px", goal_s, "no marker in the picture"),
        ]
    edged = [m for m in markers if m.edge_width_px is not None]
    width = _median(m.edge_width_px for m in edged)
    ratio = _median(2 * m.edge_width_px / m.diameter_px for m in edged if m.diameter_px)
    if width is None or ratio is None:
        focus = _unknown("focus", "focus", "px", goal_f, f"no clear edge on any of the {len(markers)} markers")
    elif width > s.edge_width_max_px or ratio > s.edge_ratio_max:
        focus = Verdict(
            "focus",
            "focus",
            ADJUST,
            width,
            "px",
            goal_f,
            f"turn the focus ring: the markers' edges are {width:.1f} px wide "
            f"({ratio:.2f} of their radius), goal ≤ {s.edge_width_max_px:g} px "
            f"(≤ {s.edge_ratio_max:g}); turn it until the width is smallest",
        )
    else:
        focus = Verdict(
            "focus",
            "focus",
            GOOD,
            width,
            "px",
            goal_f,
            f"the markers' edges are {width:.1f} px wide ({ratio:.2f} of their radius; median of {len(edged)})",
        )
    sizes = [m.diameter_px for m in markers if m.diameter_px]
    small, big, mid = min(sizes), max(sizes), float(np.median(sizes))
    span = f"{small:.1f}" if abs(big - small) < 0.05 else f"{small:.1f}-{big:.1f}"
    if small < s.marker_diameter_min_px:
        size = Verdict(
            "size",
            "marker size",
            ADJUST,
            mid,
            "px",
            goal_s,
            f"zoom in (or use larger markers): markers are {span} px across, goal ≥ {s.marker_diameter_min_px:g} px",
        )
    elif big > s.marker_diameter_max_px:
        size = Verdict(
            "size",
            "marker size",
            ADJUST,
            mid,
            "px",
            goal_s,
            f"zoom out: markers are {span} px across, goal ≤ {s.marker_diameter_max_px:g} px",
        )
    else:
        size = Verdict("size", "marker size", GOOD, mid, "px", goal_s, f"markers are {span} px across")
    return [focus, size]


def level_verdicts(markers, background: float, has_off: bool, s: AimSettings) -> list[Verdict]:
    """Brightness: the markers' contrast and the background with the LED on; what the markers
    keep with it off."""
    goal_c, goal_b = f"≥ {s.contrast_min:g} grey levels", f"≤ {s.background_max:g} grey levels"
    goal_o = f"≤ {s.led_off_share_max:.0%} of the LED-on contrast"
    on = _median(m.contrast for m in markers)
    if on is None:
        contrast = _unknown("contrast", "LED on: markers", "grey levels", goal_c, "no marker in the picture")
    elif on < s.contrast_min:
        contrast = Verdict(
            "contrast",
            "LED on: markers",
            ADJUST,
            on,
            "grey levels",
            goal_c,
            f"LED too weak: markers {on:.0f} grey levels over the background, goal "
            f"{s.contrast_min:g}; aim the LED ring at the markers, raise the exposure or the gain",
        )
    else:
        contrast = Verdict(
            "contrast",
            "LED on: markers",
            GOOD,
            on,
            "grey levels",
            goal_c,
            f"markers {on:.0f} grey levels over the background",
        )
    if background > s.background_max:
        back = Verdict(
            "background",
            "LED on: background",
            ADJUST,
            background,
            "grey levels",
            goal_b,
            f"background too bright: {background:.0f} grey levels, goal ≤ {s.background_max:g}; "
            "dim the room's lights or lower the exposure",
        )
    else:
        back = Verdict(
            "background",
            "LED on: background",
            GOOD,
            background,
            "grey levels",
            goal_b,
            f"background {background:.0f} grey levels",
        )
    off = _median(m.contrast_off for m in markers)
    if not has_off:
        led = _unknown("led_off", "LED off", "%", goal_o, "this camera cannot switch its LED")
    elif on is None or off is None or on <= 0:
        led = _unknown("led_off", "LED off", "%", goal_o, "no marker in the picture")
    else:
        share = max(off, 0.0) / on
        if share > s.led_off_share_max:
            led = Verdict(
                "led_off",
                "LED off",
                ADJUST,
                100 * share,
                "%",
                goal_o,
                f"markers still bright with the LED off ({share:.0%} of their LED-on contrast, goal "
                f"≤ {s.led_off_share_max:.0%}): room light reaches them, or the LED does not switch off",
            )
        else:
            led = Verdict(
                "led_off",
                "LED off",
                GOOD,
                100 * share,
                "%",
                goal_o,
                f"markers fade to {share:.0%} of their contrast with the LED off",
            )
    return [contrast, back, led]


def _turn_words(right_deg: float, up_deg: float, approx: bool) -> str:
    about = "about " if approx else ""
    parts = []
    if abs(right_deg) >= 0.05:
        parts.append(f"{about}{abs(right_deg):.1f}° {'right' if right_deg > 0 else 'left'}")
    if abs(up_deg) >= 0.05:
        parts.append(f"{about}{abs(up_deg):.1f}° {'up' if up_deg > 0 else 'down'}")
    return "aim " + " and ".join(parts) if parts else "aim as it is"


def picture_shift(reference, markers, tol_px: float = 4.0) -> tuple[float, float, int] | None:
    """How far the picture moved since ``reference`` (marker positions, px, e.g. the drift
    baseline's): the translation most marker pairs agree on (within ``tol_px``), refined as
    their mean, and how many agree; None when no two agree (one, when only one is seen)."""
    ref = np.asarray(reference, float).reshape(-1, 2)
    seen = np.array([(m.x, m.y) for m in markers if not m.cut], float).reshape(-1, 2)
    if not len(ref) or not len(seen):
        return None
    cands = (seen[None, :, :] - ref[:, None, :]).reshape(-1, 2)
    best, best_n = None, 0
    for d in cands:
        moved = ref + d
        near = np.linalg.norm(seen[None, :, :] - moved[:, None, :], axis=2).min(axis=1) <= tol_px
        if near.sum() > best_n:
            best, best_n = d, int(near.sum())
    if best is None or best_n < min(2, len(seen)):
        return None
    moved = ref + best
    dist = np.linalg.norm(seen[None, :, :] - moved[:, None, :], axis=2)
    pairs = [(i, int(dist[i].argmin())) for i in range(len(ref)) if dist[i].min() <= tol_px]
    d = np.mean([seen[j] - ref[i] for i, j in pairs], axis=0)
    return float(d[0]), float(d[1]), len(pairs)


def _reference_verdict(reference, markers, size, f, approx, s: AimSettings, goal, name) -> Verdict | None:
    """Aim against the reference markers: the turn that puts the picture back where it was."""
    shift = picture_shift(reference, markers)
    if shift is None:
        return None
    dx, dy, n = shift
    w, h = size
    ref = np.asarray(reference, float).reshape(-1, 2) + (dx, dy)
    gone = int(np.sum((ref[:, 0] < 0) | (ref[:, 0] > w - 1) | (ref[:, 1] < 0) | (ref[:, 1] > h - 1)))
    moved = math.hypot(dx, dy)
    if moved <= s.reference_shift_max_px and not gone:
        return Verdict(
            "aim",
            "aim",
            GOOD,
            moved,
            "px",
            goal,
            f"the picture is {moved:.1f} px from {name} ({n} of its {len(ref)} markers found)",
        )
    # content moved right (dx > 0): the camera turned left; put it back: turn right
    deg = lambda px: math.degrees(math.atan2(px, f))  # noqa: E731
    turn_right, turn_up = deg(dx), -deg(dy)
    lost = (
        f"{gone} of the {len(ref)} markers of {name} out of the picture"
        if gone
        else f"all {len(ref)} markers of {name} in the picture"
    )
    steps = [
        f"{abs(v):.0f} px {word}"
        for v, word in ((dx, "right" if dx > 0 else "left"), (dy, "down" if dy > 0 else "up"))
        if abs(v) >= 0.5
    ]
    text = f"{_turn_words(turn_right, turn_up, approx)}: {lost}; the picture moved {' and '.join(steps) or 'less than 1 px'} since {name}"
    if approx:
        text += f" (angle from a {s.nominal_focal_px:g} px lens: no calibration)"
    return Verdict(
        "aim", "aim", ADJUST, moved, "px", goal, text, {"right_deg": round(turn_right, 2), "up_deg": round(turn_up, 2)}
    )


def aim_verdict(
    markers, size, focal_px: float | None, s: AimSettings, reference=None, reference_name: str = "the drift baseline"
) -> Verdict:
    """With ``reference`` (where the markers were, px: the drift baseline's wall markers): the
    turn that puts the picture back where it was, counting the markers now out of it. Without
    (or when no marker matches it): every marker (those cut by the border too)
    ``edge_margin_px`` inside the picture, and the turn that brings the outermost ones in."""
    w, h = size
    goal = f"every marker ≥ {s.edge_margin_px:g} px inside the picture"
    f, approx = (focal_px, False) if focal_px else (s.nominal_focal_px, True)
    if reference is not None and len(reference):
        goal_r = f"within {s.reference_shift_max_px:g} px of {reference_name}, every marker in the picture"
        found = _reference_verdict(reference, markers, size, f, approx, s, goal_r, reference_name)
        if found is not None:
            return found
    if not markers:
        return Verdict(
            "aim",
            "aim",
            ADJUST,
            None,
            "markers",
            goal,
            "no marker in the picture: aim at the wall markers (the phantom in the FOV)",
        )
    m = s.edge_margin_px
    half = [(mk.diameter_px or 0.0) / 2 for mk in markers]
    xs, ys = np.array([mk.x for mk in markers]), np.array([mk.y for mk in markers])
    r = np.array(half)
    right = max(0.0, float(np.max(m - (xs - r))))  # content must move right by this
    left = max(0.0, float(np.max((xs + r) - (w - 1 - m))))  # ... left
    down = max(0.0, float(np.max(m - (ys - r))))
    up = max(0.0, float(np.max((ys + r) - (h - 1 - m))))
    out = [
        mk
        for mk, x, y, rr in zip(markers, xs, ys, r)
        if mk.cut or x - rr < m or x + rr > w - 1 - m or y - rr < m or y + rr > h - 1 - m
    ]
    unref = (
        ""
        if reference is not None and len(reference)
        else f" (no {reference_name.removeprefix('the ')} to say whether markers left it)"
    )
    if not out:
        return Verdict(
            "aim", "aim", GOOD, 0.0, "markers", goal, f"all {len(markers)} markers inside the picture{unref}"
        )
    deg = lambda px: math.degrees(math.atan2(px, f))  # noqa: E731
    cut = sum(1 for mk in out if mk.cut)
    what = f"{len(out)} marker{'s' if len(out) > 1 else ''} at the picture's edge" + (
        f" ({cut} cut by it)" if cut else ""
    )
    if (right and left) or (down and up):
        return Verdict(
            "aim",
            "aim",
            ADJUST,
            float(len(out)),
            "markers",
            goal,
            f"zoom out or bring the markers closer together: {what} on opposite sides",
        )
    # content right = camera turns left; content down = camera tilts up
    turn_right, turn_up = deg(left) - deg(right), deg(down) - deg(up)
    text = f"{_turn_words(turn_right, turn_up, approx)}: {what}{unref}"
    if approx:
        text += f" (angle from a {s.nominal_focal_px:g} px lens: no calibration)"
    return Verdict(
        "aim",
        "aim",
        ADJUST,
        float(len(out)),
        "markers",
        goal,
        text,
        {"right_deg": round(turn_right, 2), "up_deg": round(turn_up, 2)},
    )


def fov_verdict(view, s: AimSettings, no_view: str) -> Verdict:
    """The SPECT FOV's centre within ``fov_centre_max_deg`` of the optical axis."""
    goal = f"FOV centre within {s.fov_centre_max_deg:g}° of the picture's centre"
    if view is None:
        return _unknown("fov", "SPECT FOV", "°", goal, no_view)
    right, down = view.angles_deg(view.centre)
    off = math.hypot(right, down)
    inside = view.fov().share_inside
    where = f"{inside:.0%} of its outline in the picture"
    if off > s.fov_centre_max_deg:
        turn = _turn_words(right, -down, False)
        return Verdict(
            "fov",
            "SPECT FOV",
            ADJUST,
            off,
            "°",
            goal,
            f"{turn}: the FOV centre is {off:.1f}° off the picture's centre ({where})",
            {"right_deg": round(right, 2), "up_deg": round(-down, 2)},
        )
    return Verdict(
        "fov", "SPECT FOV", GOOD, off, "°", goal, f"the FOV centre is {off:.1f}° off the picture's centre ({where})"
    )


def gantry_verdict(markers, view, s: AimSettings, no_view: str) -> Verdict:
    """How many markers are seen through the gantry's opening (the wall markers, when nothing
    is on the table)."""
    goal = f"≥ {s.min_wall_markers} markers through the gantry's opening"
    if view is None:
        return _unknown("gantry", "through the gantry", "markers", goal, no_view)
    # with a reference, only the wall markers count (vision/marker_roles.py): a patient's or the
    # phantom's markers are seen through the opening too
    seen = [mk for mk in markers if mk.through_gantry and not mk.cut and getattr(mk, "role", "") in ("", "wall")]
    n, hidden = len(seen), sum(1 for mk in markers if mk.through_gantry is False and not mk.cut)
    beside = f"; {hidden} beside it (hidden by the gantry's housing)" if hidden else ""
    if n < s.min_wall_markers:
        return Verdict(
            "gantry",
            "through the gantry",
            ADJUST,
            float(n),
            "markers",
            goal,
            f"only {n} marker{'s' if n != 1 else ''} through the gantry's opening, goal "
            f"{s.min_wall_markers}{beside}: aim through the opening, or move the wall markers into it",
        )
    return Verdict(
        "gantry",
        "through the gantry",
        GOOD,
        float(n),
        "markers",
        goal,
        f"{n} markers through the gantry's opening{beside}",
    )
