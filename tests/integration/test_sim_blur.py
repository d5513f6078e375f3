"""Motion blur in the simulated cameras (sim_devices/render.py): a marker that moves during
the exposure is smeared along its motion, centred where it was at the frame's instant; a
static scene renders exactly as without an exposure."""

import numpy as np
import pytest

from vts_hw.sim_devices.axis_params import Profile
from vts_hw.sim_devices.render import Renderer
from vts_hw.sim_devices.scene import Marker, Scene

T0 = 1_700_000_000.0


class Sliding:
    """A sphere gliding along world X at ``speed`` mm/s (a body on the table, duck-typed)."""

    def __init__(self, start, speed):
        self.name = "slider"
        self.start, self.speed = np.asarray(start, float), float(speed)
        self.markers = [Marker("M", np.zeros(3), np.array([0, 1.0, 0]), 15.0, "sphere")]

        class _Key:
            def at(self, t):
                return round(float(t), 6)

        self.pose = _Key()

    def markers_at(self, t, table_offset):
        c = self.start + [self.speed * (t - T0), 0.0, 0.0] + np.asarray(table_offset, float)
        return [Marker("M", c, np.array([0, 1.0, 0]), 15.0, "sphere")]


def _scene(speed):
    s = Scene.reference(seed=0, start_epoch=T0)
    s.add_body(Sliding((-30.0, 0.0, 0.0), speed))
    for cam in s.cameras:
        s.set_led(cam, True, T0)
    return s


def _blob(img, bg, u, v, half=20):
    """Centroid and second moments (x, y) of the marker's light around (u, v)."""
    u0, v0 = int(round(u)), int(round(v))
    win = (
        img[v0 - half : v0 + half + 1, u0 - half : u0 + half + 1].astype(float)
        - bg[v0 - half : v0 + half + 1, u0 - half : u0 + half + 1]
    )
    win = np.clip(win, 0, None)
    yy, xx = np.mgrid[v0 - half : v0 + half + 1, u0 - half : u0 + half + 1]
    w = win.sum()
    cx, cy = (win * xx).sum() / w, (win * yy).sum() / w
    return np.array([cx, cy]), ((win * (xx - cx) ** 2).sum() / w, (win * (yy - cy) ** 2).sum() / w)


def test_a_fast_marker_is_smeared_along_its_motion_centred_at_mid_exposure():
    fast, still = _scene(1500.0), _scene(0.0)  # 1.5 m/s: 12 mm (~11 px) in 8 ms
    r_fast, r_still = Renderer(fast, noise_sigma=0), Renderer(still, noise_sigma=0)
    t = T0 + 0.02  # the fast one passes x = 0
    for cam in ("cam1", "cam2"):
        truth = {m: (u, v) for m, u, v in fast.truth(cam, t)}["M"]
        bg = r_fast._bg[cam]
        c_fast, (sxx_f, syy_f) = _blob(r_fast.clean(cam, t), bg, *truth)
        c_still, (sxx_s, syy_s) = _blob(r_still.clean(cam, t), bg, *{m: (u, v) for m, u, v in still.truth(cam, t)}["M"])
        # along the motion (image x, nearly): much longer; across it: as without motion
        assert sxx_f > sxx_s + 5.0
        assert syy_f == pytest.approx(syy_s, rel=0.15)
        assert np.linalg.norm(c_fast - truth) < 0.1
        # the same frame drawn with no exposure: a sharp disk where the smear is centred
        sharp = Renderer(fast, noise_sigma=0, exposure_s=0.0)
        c_sharp, (sxx_0, _) = _blob(sharp.clean(cam, t), bg, *truth)
        assert sxx_0 == pytest.approx(sxx_s, rel=0.1) and np.linalg.norm(c_sharp - c_fast) < 0.1


def test_a_slow_marker_is_drawn_sharp_and_a_static_scene_as_without_exposure():
    slow = _scene(10.0)  # 0.08 mm in 8 ms: under 0.2 px, not smeared
    assert np.array_equal(
        Renderer(slow, noise_sigma=0).clean("cam1", T0 + 1),
        Renderer(slow, noise_sigma=0, exposure_s=0.0).clean("cam1", T0 + 1),
    )
    s = Scene.reference(seed=0, start_epoch=T0)
    s.add_phantom()
    for cam in s.cameras:
        s.set_led(cam, True, T0)
    r, r0 = Renderer(s), Renderer(s, exposure_s=0.0)
    for cam in s.cameras:
        assert np.array_equal(r.clean(cam, T0 + 3), r0.clean(cam, T0 + 3))
        assert np.array_equal(r.render(cam, T0 + 3, noise=False), r0.render(cam, T0 + 3, noise=False))
        r.clean(cam, T0 + 4)
    assert r.stats == {"hits": 4, "misses": 2}  # the static scene stays cached


def test_the_exposure_comes_from_the_camera_model():
    assert Profile.load("p1375").exposure_ms == 8.0 and Profile.load("axis211").exposure_ms == 10.0
    from vts_hw.sim_devices.rig import SimRig

    rig = SimRig(n_cameras=2, firmware="axis211")
    assert rig.renderer.exposure == {"cam1": 0.010, "cam2": 0.010}
