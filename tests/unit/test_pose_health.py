"""Every pose says how sure it is (issue 33 §2): the one rule of vts_hw.pose_health -- its states and
reasons, the documented formula's values, and the confidence monotone in each input (more markers or
cameras never lower it, more residual or age never raise it)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vts_hw.motion.body_pose import POOR_FIT_MM as BODY_POOR_FIT_MM
from vts_hw.pose_health import BOUNDED, KNOWN, NOT_KNOWN, POOR_FIT_MM, health_series, pose_health


def test_states_and_why():
    assert pose_health(8, 8, 0.05, 3, 0.0).state == KNOWN and pose_health(8, 8, 0.05).why == ""
    h = pose_health(2, 8, float("nan"))
    assert (h.state, h.why, h.confidence) == (NOT_KNOWN, "fewer than 3 markers (2 of 8)", 0.0)
    assert pose_health(8, 8, float("nan")).why == "no pose fitted"
    assert pose_health(8, 8, 0.05, frames=False).why == "no frames"
    assert (
        pose_health(8, 8, 0.05, age_s=6.0).state == NOT_KNOWN and "6.00 s old" in pose_health(8, 8, 0.05, age_s=6).why
    )
    assert pose_health(8, 8, 0.45) == pose_health(8, 8, 0.45) and pose_health(8, 8, 0.45).state == BOUNDED
    assert pose_health(8, 8, 0.45).why == "fit residual 0.45 mm over 0.3 mm"
    assert pose_health(3, 8, 0.05).why == "3 markers of 8: a wrong point cannot show"
    assert pose_health(8, 8, 0.05, age_s=0.8).state == BOUNDED
    assert pose_health(8, 8, 0.5, poor_fit_mm=1.0).state == KNOWN  # the live model's own line
    for h in (pose_health(2, 8, 0.1), pose_health(8, 8, 0.1, frames=False)):
        assert "," not in h.why and h.to_json()["confidence"] == 0.0


def test_the_documented_formula():
    # 8 of 8 markers, 0.15 mm, 3 cameras, 0.1 s: 1 * 1/(1+0.25) * (1-0.4/3) * exp(-0.05)
    assert pose_health(8, 8, 0.15, 3, 0.1).confidence == pytest.approx(0.8 * (1 - 0.4 / 3) * math.exp(-0.05))
    assert pose_health(3, 8, 0.0, 2, 0.0).confidence == pytest.approx(math.sqrt(1 / 6) * 0.8)
    assert pose_health(8, 8, 0.0, None, 0.0).confidence == pytest.approx(0.8)  # cameras unknown: 2
    assert POOR_FIT_MM == BODY_POOR_FIT_MM  # one poor-fit line for the offline pose's quality and its health


def test_a_series_gives_one_row_each_and_counts():
    h = health_series([8, 2, 5, 8], 8, [0.05, np.nan, 0.5, 0.05], [2, 2, 3, 4], 0.0, [True, True, True, False])
    assert list(h.state) == [KNOWN, NOT_KNOWN, BOUNDED, NOT_KNOWN]
    assert h.counts() == {KNOWN: 1, BOUNDED: 1, NOT_KNOWN: 2}
    assert h.confidence[1] == h.confidence[3] == 0.0 and 0 < h.confidence[2] < h.confidence[0] <= 1


inputs = st.tuples(st.integers(0, 12), st.floats(0, 3), st.floats(1, 6), st.floats(0, 8))


@settings(max_examples=150, deadline=None)
@given(inputs, st.integers(0, 3), st.floats(0, 2), st.floats(0, 3), st.floats(0, 4))
def test_confidence_is_monotone_in_each_input(x, dn, dr, dc, da):
    n, rms, cams, age = x
    c = lambda n, r, k, a: pose_health(n, 12, r, k, a).confidence  # noqa: E731
    base = c(n, rms, cams, age)
    assert 0.0 <= base <= 1.0
    assert c(min(n + dn, 12), rms, cams, age) >= base
    assert c(n, rms + dr, cams, age) <= base
    assert c(n, rms, cams + dc, age) >= base
    assert c(n, rms, cams, age + da) <= base
