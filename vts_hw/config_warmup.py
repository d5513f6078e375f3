"""rig.yaml's ``warmup:`` section: how the commissioning's warm-up step watches the cameras'
pictures settle (procedures/warmup.py). The limit on the rate is a tolerance window like any
other (``tolerances: warmup_rate_px_min``, default OK ≤ 0.05 px/min).

The defaults suit a real room: a sample a minute, six samples (a 5-minute window, about half
the time constant of a warming fixed camera), three snapshots each. A test's room uses
fractions of a second.
"""

from __future__ import annotations

from pydantic import Field

from vts_hw.config_base import Strict


class WarmupSettings(Strict):
    interval_s: float = Field(
        default=60.0, gt=0, le=3600, description="seconds between two samples of the wall markers' position"
    )
    samples: int = Field(
        default=6, ge=3, le=100, description="samples in the window the rate (px/min) is fitted over (3 or more)"
    )
    frames: int = Field(default=3, ge=1, le=25, description="snapshots averaged in each sample")
