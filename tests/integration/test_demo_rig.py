"""The demo's camera tour (what `vts demo` step 1 prints): two simulated cameras through the
real driver, LED snapshots that differ, a complete recording; run twice into one folder."""

import cv2
import numpy as np

from vts_hw.sim_devices.scenarios.demo_rig import camera_tour


def test_the_camera_tour_runs_again_into_the_same_folder(tmp_path):
    said = []
    for _ in range(2):
        tour = camera_tour(tmp_path, 1.0, say=said.append)
        assert tour.manifest["status"] == "complete"
        assert [s.source for s in tour.streams] == ["cam1", "cam2"] and all(s.frames >= 5 for s in tour.streams)
    assert any(m.startswith("simulated rig up: cam1 at http://127.0.0.1:") for m in said)
    for c in tour.cameras:
        assert c.lit_bright_px > c.dark_bright_px + 20
        lit = cv2.imread(str(c.lit), cv2.IMREAD_GRAYSCALE)
        assert int((lit > 128).sum()) == c.lit_bright_px and np.isfinite(c.clock_offset_s)
