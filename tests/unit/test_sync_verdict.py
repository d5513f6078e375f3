"""The sync check is judged by the tolerance table's sync windows, as every QA result is."""

import pytest

from vts_hw.procedures.sync_verdict import sync_verdict, sync_windows
from vts_hw.tolerance import DEFAULT_TOLERANCES, State, Window


def summary(max_dt_s, both=4, spect_only=0, vts_only=0):
    return {
        "events": both + spect_only + vts_only,
        "events_both": both,
        "events_spect_only": spect_only,
        "events_vts_only": vts_only,
        "max_abs_dt_s": max_dt_s,
    }


@pytest.mark.parametrize(
    "s,state,words",
    [
        (summary(0.004), State.OK, "every one of the 4 event(s) agrees within 20 ms; no problems found"),
        (summary(0.045), State.TOLERANCE, "more than the 20 ms goal"),
        (summary(0.150), State.ACTION, "an event differs by 150 ms, more than 100 ms"),
        (summary(0.004, spect_only=1), State.TOLERANCE, "1 event(s) seen by one system only"),
        (summary(None, both=0, spect_only=2), State.ACTION, "no motion event was seen by both"),
    ],
)
def test_default_windows(s, state, words):
    got, reason = sync_verdict(s)
    assert got is state and words in reason


def test_the_rig_tolerance_table_judges():
    assert set(sync_windows()) <= set(DEFAULT_TOLERANCES)  # rig.yaml may override them by name
    strict = sync_windows({"sync_max_abs_dt_ms": Window(tolerance_high=5.0, action_high=10.0, unit="ms")})
    assert sync_verdict(summary(0.004), strict)[0] is State.OK
    state, reason = sync_verdict(summary(0.008), strict)
    assert state is State.TOLERANCE and "more than the 5 ms goal" in reason
    assert sync_verdict(summary(0.012), strict)[0] is State.ACTION
    assert sync_verdict(summary(0.012))[0] is State.OK  # the defaults are untouched
