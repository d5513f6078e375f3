"""The wall-marker drift analysis, scored against the simulated scene's truth."""

import json

import cv2
import numpy as np
import pytest

from vts_hw import catalog
from vts_hw.procedures.drift import DriftAnalysis
from vts_hw.sim_devices.render import Renderer, encode
from vts_hw.sim_devices.scene import Scene
from vts_hw.tolerance import State, Window
from vts_hw.vision.wall_markers import baseline_from_frames

DAY = 86400.0


@pytest.fixture(scope="module")
def world():
    scene = Scene.reference(seed=3)
    return scene, Renderer(scene, seed=5)


def _jpegs(renderer, cam, t, n, led=True, edit=None):
    scene = renderer.scene if hasattr(renderer, "scene") else None
    out = []
    for k in range(n):
        if scene is not None:
            scene.set_led(cam, led, t - 1.0)
        img = renderer.render(cam, t + k * 0.04)
        if edit is not None:
            img = edit(img.copy())
        out.append(encode(img, 75))
    return out


def _truth_shift(scene, cam, t0, t1):
    a = {m: (u, v) for m, u, v in scene.truth(cam, t0) if m.startswith("W")}
    b = {m: (u, v) for m, u, v in scene.truth(cam, t1) if m.startswith("W")}
    d = np.array([np.subtract(b[k], a[k]) for k in a])
    return d.mean(axis=0)


@pytest.mark.parametrize("cam", ["cam1", "cam2"])
def test_measured_drift_matches_the_injected_drift(world, cam):
    scene, r = world
    t0 = scene.start_epoch + 10.0
    base = baseline_from_frames(cam, _jpegs(r, cam, t0, 5), t0)
    assert len(base.markers) == 5 and [m.id for m in base.markers] == [f"M{i}" for i in range(1, 6)]
    for days in (20, 45, 90):
        t1 = t0 + days * DAY
        d = DriftAnalysis.from_frames(cam, base, _jpegs(r, cam, t1, 5), _jpegs(r, cam, t1 + 1, 1, led=False)[0])
        d.analyze()
        truth = _truth_shift(scene, cam, t0, t1)
        assert abs(d.drift_px[0] - truth[0]) <= 0.05 and abs(d.drift_px[1] - truth[1]) <= 0.05
        assert np.hypot(*truth) > 0.2  # there really was drift to measure
        assert d.missing == [] and d.strays == [] and d.led_off_visible == 0


def test_missing_marker_stray_blob_and_stuck_led(world):
    scene, r = world
    cam, t0 = "cam1", scene.start_epoch + 5.0
    base = baseline_from_frames(cam, _jpegs(r, cam, t0, 3), t0)
    hide = base.markers[2]

    def edit(img):
        cv2.circle(img, (int(round(hide.x)), int(round(hide.y))), 16, 20, -1)  # covered marker
        cv2.circle(img, (320, 240), 9, 230, -1)  # a new bright thing
        return img

    on = _jpegs(r, cam, t0 + 60, 5, edit=edit)
    d = DriftAnalysis.from_frames(cam, base, on, on[0]).analyze()  # LED "off" frame still lit
    assert d.missing == [hide.id]
    assert len(d.strays) == 1 and np.hypot(d.strays[0][0] - 320, d.strays[0][1] - 240) < 1.0
    assert d.led_off_visible == 4
    states = {(m.subject, m.metric): m.state for m in d.measures}
    assert states[(cam, "markers_missing")] == State.TOLERANCE
    assert states[(cam, "stray_blobs")] == State.TOLERANCE
    assert states[(cam, "led_off_visible")] == State.ACTION
    assert states[(f"{cam}/{hide.id}", "drift_x_px")] == State.ACTION  # not measured
    assert d.state == State.ACTION
    text = d.results()
    assert "MISSING markers: M3" in text and "STRAY" in text and "still bright" in text


def test_tolerances_from_config_change_the_state(world):
    from vts_hw.tolerance import Window

    scene, r = world
    cam, t0 = "cam2", scene.start_epoch + 5.0
    base = baseline_from_frames(cam, _jpegs(r, cam, t0, 3), t0)
    on = _jpegs(r, cam, t0 + 60 * DAY, 3)
    off = _jpegs(r, cam, t0 + 60 * DAY + 1, 1, led=False)[0]
    loose = DriftAnalysis.from_frames(cam, base, on, off).analyze()
    tight = DriftAnalysis.from_frames(cam, base, on, off).analyze(
        {"drift_x_px": Window.symmetric(0.01, 0.02, "px"), "drift_y_px": Window.symmetric(0.01, 0.02, "px")}
    )
    assert loose.state == State.OK and tight.state == State.ACTION


def test_results_data_and_plot(world, tmp_path):
    scene, r = world
    cam, t0 = "cam1", scene.start_epoch + 5.0
    base = baseline_from_frames(cam, _jpegs(r, cam, t0, 3), t0)
    d = DriftAnalysis.from_frames(
        cam, base, _jpegs(r, cam, t0 + 30 * DAY, 3), _jpegs(r, cam, t0 + 30 * DAY + 1, 1, led=False)[0]
    ).analyze()
    data = json.loads(json.dumps(d.results_data()))
    assert data["software_version"] and data["analyzed"] and data["state"] == "OK"
    assert len(data["markers"]) == 5 and data["drift_mm"]["x"] == pytest.approx(data["drift_px"]["x"] * 1.25, abs=1e-3)
    d.plot(tmp_path / "drift.png")
    img = cv2.imread(str(tmp_path / "drift.png"))
    assert img is not None and img.shape[0] > 300
    with pytest.raises(RuntimeError):
        DriftAnalysis.from_frames(cam, base, [], None).results()


def test_the_catalog_entries_own_windows_judge_the_drift(world, monkeypatch):
    """The analysis reads its default windows from ``catalog.windows()`` (decision 0101), so a
    window a catalog entry brings for a metric of its own is in its table like the tolerance
    table's, and the rig's given windows still go on top."""
    own = catalog.Procedure(
        "drift-extra",
        "extra drift",
        "room",
        (("drift_extra_px", "px"),),
        windows=(("drift_extra_px", Window(action_high=3.0)),),
    )
    monkeypatch.setattr(catalog, "PROCEDURES", (*catalog.PROCEDURES, own))
    scene, r = world
    cam, t0 = "cam2", scene.start_epoch + 5.0
    base = baseline_from_frames(cam, _jpegs(r, cam, t0, 3), t0)
    on = _jpegs(r, cam, t0 + 1.0, 3)
    off = _jpegs(r, cam, t0 + 2.0, 1, led=False)[0]
    given = Window.symmetric(0.01, 0.02, "px")
    d = DriftAnalysis.from_frames(cam, base, on, off).analyze({"drift_x_px": given})
    assert d.tolerances["drift_extra_px"] == Window(action_high=3.0)
    assert d.tolerances["drift_x_px"] == given
