"""The simulated SPECT gantry: two detector heads turning step-and-shoot about the axis, hiding
markers from some cameras at some angles -- in the truth and in the rendered images alike."""

import numpy as np
import pytest

from vts_hw.sim_devices.gantry import Gantry
from vts_hw.sim_devices.render import Renderer
from vts_hw.sim_devices.scene import Marker, RigidBody, Scene

T0 = 1_700_000_000.0


def test_step_and_shoot_turns_in_steps_and_stays():
    g = Gantry()
    assert g.angle_at(T0) == g.park_deg and g.radius_at(T0) == 400.0  # parked, drawn back
    acq = g.step_and_shoot(T0 + 10, step_deg=3.0, n_steps=4, dwell_s=2.0, move_s=1.0, radius_mm=230.0)
    assert g.angle_at(T0 + 9.9) == 0.0 and g.radius_at(T0 + 9.9) == 400.0
    assert g.angle_at(T0 + 10) == 0.0 and g.angle_at(T0 + 11.9) == 0.0 and g.radius_at(T0 + 10) == 230.0
    assert g.angle_at(T0 + 12.5) == pytest.approx(1.5) and g.rotating(T0 + 12.5)
    assert g.angle_at(T0 + 13.5) == pytest.approx(3.0) and not g.rotating(T0 + 13.5)
    assert acq.end == pytest.approx(T0 + 10 + 4 * 3.0 + 2.0)
    assert g.angle_at(T0 + 100) == pytest.approx(12.0) and not g.rotating(T0 + 100)
    g.park()
    assert g.angle_at(T0 + 100) == 0.0 and g.radius_at(T0 + 100) == 400.0


def test_heads_are_the_size_of_real_ones_and_face_the_axis():
    g = Gantry()
    g.step_and_shoot(T0, start_deg=90.0, radius_mm=250.0)
    for corners, sign in zip(g.corners(T0), (1, -1)):
        size = np.ptp(corners, axis=0)
        assert size == pytest.approx([200.0, 540.0, 400.0])  # at 90 deg: thickness along X
        assert np.abs(corners[:, 0]).min() == pytest.approx(250.0)  # the face 250 mm from the axis
        assert np.sign(corners[:, 0].mean()) == sign


def band_scene(n_cameras=4):
    s = Scene.reference(seed=0, n_cameras=n_cameras, start_epoch=T0, gantry=True)
    s.add_body(
        RigidBody("band", [Marker("B1", np.array([0.0, 170.0, 0.0]), np.array([0.0, 1.0, 0.0]), 13.0, "sphere")])
    )
    for c in s.camera_names:
        s.set_led(c, True)
    return s


def test_a_marker_hidden_from_a_camera_at_one_angle_is_seen_at_another():
    s = band_scene()
    s.gantry.step_and_shoot(T0, step_deg=3.0, n_steps=120, dwell_s=1.0, move_s=0.5, radius_mm=230.0)
    seen = {c: [] for c in s.camera_names}
    times = T0 + np.arange(120) * 1.5  # one instant per stop: 0, 3, 6 ... 357 deg
    for t in times:
        for c in s.camera_names:
            seen[c].append("B1" in {m for m, _, _ in s.truth(c, t)})
    seen = {c: np.array(v) for c, v in seen.items()}
    for c in s.camera_names:  # every camera loses the marker at some angles, not at all
        assert 0 < (~seen[c]).sum() < len(times) // 2, c
    both = np.array([sum(seen[c][k] for c in s.camera_names) for k in range(len(times))])
    assert both.min() < 4 and both.max() == 4
    # the rendered image agrees with the truth: bright where seen, background where hidden
    r = Renderer(s, noise_sigma=0.0)
    cam = "cam1"
    k_hidden, k_seen = int(np.flatnonzero(~seen[cam])[0]), int(np.flatnonzero(seen[cam])[0])
    u, v = np.rint(s.camera_at(cam, times[k_seen]).project([[0.0, 170.0, 0.0]])[0]).astype(int)
    assert r.render(cam, times[k_seen])[v, u] > 150
    assert r.render(cam, times[k_hidden])[v, u] < 40
    # the same scene without heads hides nothing
    s.gantry = None
    assert all("B1" in {m for m, _, _ in s.truth(c, t)} for c in s.camera_names for t in times)


@pytest.mark.parametrize("n_cameras", [2, 4, 8])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_parked_heads_hide_no_wall_marker(seed, n_cameras):
    """The daily drift QA runs with the heads parked: every camera sees its five wall markers."""
    s = Scene.reference(seed=seed, n_cameras=n_cameras, start_epoch=T0, gantry=True)
    for c in s.camera_names:
        assert len([m for m, _, _ in s.truth(c, T0) if m.startswith("W")]) == 5
    s.gantry.step_and_shoot(T0 + 1, start_deg=30.0, radius_mm=230.0)  # on the orbit some are hidden
    assert (
        sum(len([m for m, _, _ in s.truth(c, T0 + 1.5) if m.startswith("W")]) for c in s.camera_names) < 5 * n_cameras
    )


def test_two_cameras_keep_the_reference_rig():
    """N = 2 is today's stereo pair over the head: the gantry parked changes no image."""
    plain = Scene.reference(seed=0, start_epoch=T0)
    with_heads = Scene.reference(seed=0, start_epoch=T0, gantry=True)
    four = Scene.reference(seed=0, n_cameras=4, start_epoch=T0)
    for c in ("cam1", "cam2"):
        assert np.array_equal(plain.cameras[c].R, four.cameras[c].R)
        assert np.array_equal(plain.cameras[c].K, four.cameras[c].K)
        assert plain.truth(c, T0) == with_heads.truth(c, T0)
    assert plain.cameras["cam1"].center[0] == pytest.approx(-600.0)
    assert four.cameras["cam3"].center[2] == pytest.approx(3530.0)
    assert four.cameras["cam4"].center[2] == pytest.approx(3530.0)
