"""The simulated QATrack+ beside the simulated rig (`vts sim up --qatrack`), so that `vts qa push`
can be tried without a clinic's QATrack+.

The site (:class:`~vts_hw.sim_devices.qatrack_server.QATrackSim` on 127.0.0.1) gets one unit,
:data:`UNIT`, with the test lists the rig's ``qatrack:`` section maps to: ``VTS daily`` (each
camera's drift, its SD and its missing markers, for the daily and the drift QA) and ``VTS step
test``. Its token is made afresh for each rig and goes only into ``sim.env`` as
:data:`TOKEN_ENV`; rig.yaml names that variable (``token_env``), never the token. The site keeps
its instances in memory: they are gone when the rig stops.
"""

from __future__ import annotations

import secrets

from vts_hw.sim_devices.qatrack_server import QATrackSim

UNIT = "SPECT room (simulated)"
TOKEN_ENV = "VTS_SIM_QATRACK_TOKEN"
TIME_ZONE = "UTC"
DAILY_LIST, STEPS_LIST = "VTS daily", "VTS step test"
#: per camera: metric -> the macro's suffix
CAMERA_MACROS = {"drift_x_px": "dx", "drift_y_px": "dy", "drift_sd_px": "sd", "markers_missing": "missing"}
STEPS_MACROS = {
    "x/steps_slope": "x_slope",
    "y/steps_slope": "y_slope",
    "z/steps_slope": "z_slope",
    "all/steps_diff_max_mm": "diff_max",
}


def _macro(camera: str, suffix: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in camera) + "_" + suffix


def lists(cameras: list[str]) -> dict:
    """rig.yaml's ``qatrack.lists``: the daily (and drift) QA and the step test."""
    daily = {f"{c}/{m}": _macro(c, s) for c in cameras for m, s in CAMERA_MACROS.items()}
    # deliberately not sent: the per-marker values and the other checks (the run's state, in the
    # instance's comment, says how they went)
    qa = {"test_list": DAILY_LIST, "macros": daily, "ignore": ["*"]}
    return {
        "daily": qa,
        "drift": qa,
        "sphere-steps": {"test_list": STEPS_LIST, "macros": dict(STEPS_MACROS), "ignore": ["*"]},
    }


def start_site(cameras: list[str]):
    """A running simulated QATrack+ for these cameras (``.down()`` stops it)."""

    cfg = lists(cameras)
    site_lists = {DAILY_LIST: sorted(cfg["daily"]["macros"].values()), STEPS_LIST: sorted(STEPS_MACROS.values())}
    return QATrackSim(site_lists, {UNIT: list(site_lists)}, token=secrets.token_hex(16), time_zone=TIME_ZONE).up()


def section(site, cameras: list[str]) -> dict:
    """rig.yaml's ``qatrack:`` section for the running ``site`` (the token stays in the environment)."""
    return {
        "url": site.url,
        "unit": UNIT,
        "time_zone": TIME_ZONE,
        "token_env": TOKEN_ENV,
        "timeout_s": 10.0,
        "lists": lists(cameras),
    }


__all__ = ["start_site", "section", "lists", "UNIT", "TOKEN_ENV", "TIME_ZONE"]
