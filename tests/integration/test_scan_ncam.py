"""A scan on a four-camera simulated rig with the SPECT heads turning, recorded over HTTP and
processed with the rig's N-camera calibration file (cameras.json)."""

from __future__ import annotations

import numpy as np
import pytest

from vts_hw.config import load_rig
from vts_hw.drivers.registry import open_cameras
from vts_hw.procedures.scan import ScanSession
from vts_hw.sim_devices.rig import SimRig
from vts_hw.tracking.processing import process_recording
from vts_hw.vision.camera_set import load_cameras
from vts_hw.vision.registration import RigidTransform

FPS = 25.0
pytestmark = pytest.mark.timeout(600)  # a hang detector: making the frames ahead takes long on a loaded machine


def test_a_four_camera_scan_is_recorded_and_tracked(tmp_path):
    rig = SimRig(n_cameras=4, seed=3, gantry=True).start()
    try:
        rig.ntp_sync()
        rig.prerender(9.0)  # the scan's frames (the heads turning with them) made ahead
        rig_yaml, _ = rig.write(tmp_path / "rig")
        cfg = load_rig(rig_yaml)
        with rig.env():
            folder = tmp_path / "scan"
            m = ScanSession(cfg, folder, open_cameras(cfg.cameras), duration=3.0).run()
    finally:
        rig.stop()
    assert sorted(m["cameras"]) == ["cam1", "cam2", "cam3", "cam4"]
    assert rig.bank.served >= 4 * 0.9 * 3.0 * FPS and "the scene changed" not in rig.bank.missed
    for name, cam in m["cameras"].items():
        assert cam["frames"] >= 0.9 * 3.0 * FPS and cam["gaps"] == [], name
    # cameras.json is in camera 1's frame, like calibration.json: spect_mapping.json maps it
    mapping = RigidTransform.load(tmp_path / "rig" / "spect_mapping.json")
    tracks = process_recording(folder, load_cameras(tmp_path / "rig" / "cameras.json"), workers=2, mapping=mapping)
    assert tracks.camera_names == ["cam1", "cam2", "cam3", "cam4"] and len(tracks) >= 0.9 * 3.0 * FPS
    # each wall seen by the pair at its end: points from cam1+cam2 and from cam3+cam4
    sets = {tuple(np.flatnonzero(r)) for r in tracks.point_cameras}
    assert (0, 1) in sets and (2, 3) in sets
    truth = np.array([w.center for w in rig.scene.wall_markers])
    err = np.linalg.norm(tracks.xyz_spect[:, None, :] - truth[None], axis=2).min(axis=1)
    assert err.max() < 1.0  # every point is a wall marker, where it is
    # the wall markers located are those two cameras see at some time (the heads hide some)
    ids = [w.id for w in rig.scene.wall_markers]
    located = {ids[k] for k in np.linalg.norm(tracks.xyz_spect[:, None, :] - truth[None], axis=2).argmin(axis=1)}
    seen = set()
    for t in tracks.host_time[::5]:
        names = [m for c in rig.scene.camera_names for m, _, _ in rig.scene.truth(c, float(t))]
        seen |= {w for w in ids if names.count(w) >= 2}
    assert located == seen and len(seen) < 10
