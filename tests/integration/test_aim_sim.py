"""Aim and focus against the simulated cameras over HTTP (SimRig): a lens put out of focus and a
mount turned through the simulator's control API (POST /sim/optics) turn the verdicts from good
to adjust, with the right advice; the SPECT FOV lands where the calibration and mapping say."""

import json

import cv2
import numpy as np
import pytest
import requests

from vts_hw.drivers.registry import open_camera
from vts_hw.procedures.aim import aim_page, check, room_view
from vts_hw.sim_devices.sync_truth import write_true_calibration
from vts_hw.vision.aim_overlay import COLOURS


def optics(rig, cam, **changes):
    url = f"http://127.0.0.1:{rig.servers[cam].port}/sim/optics"
    r = requests.post(url, data=json.dumps(changes), timeout=10)
    return r.status_code, r.json()


@pytest.fixture()
def mapped(sim_rig, tmp_path):
    """The simulated rig's config with its true calibration and mapping named in it."""
    cal, mp = write_true_calibration(sim_rig.scene, tmp_path)
    return sim_rig.config(calibration={"stereo": str(cal), "spect": str(mp)})


def test_defocus_and_misaim_turn_good_into_adjust(sim_rig, mapped):
    with open_camera(mapped.camera("cam1")) as cam:
        first = check(cam, mapped)
        assert first.state == "good", [v.text for v in first.items]
        assert {v.item: v.state for v in first.items}["fov"] == "good"
        reference = [(m.x, m.y) for m in first.markers]  # as a drift baseline would hold them

        assert optics(sim_rig, "cam1", focus_blur_px=1.5) == (
            200,
            {"focus_blur_px": 1.5, "yaw_deg": 0.0, "pitch_deg": 0.0},
        )
        blurred = check(cam, mapped, reference=reference)
        focus = blurred.item("focus")
        assert focus.state == "adjust" and focus.text.startswith("turn the focus ring")
        assert focus.value > 2 * first.item("focus").value
        assert blurred.item("aim").state == "good"  # defocus moves nothing

        optics(sim_rig, "cam1", focus_blur_px=0.0, yaw_deg=3.0)  # the mount turned 3° to the right
        turned = check(cam, mapped, reference=reference)
        aim = turned.item("aim")
        assert turned.item("focus").state == "good"
        assert aim.state == "adjust" and aim.text.startswith("aim 3.0° left"), aim.text
        assert aim.turn["right_deg"] == pytest.approx(-3.0, abs=0.2) and abs(aim.turn["up_deg"]) < 0.2

        optics(sim_rig, "cam1", yaw_deg=0.0, pitch_deg=-2.0)  # tilted 2° down
        tilted = check(cam, mapped, reference=reference).item("aim")
        assert tilted.state == "adjust" and tilted.text.startswith("aim 2.0° up"), tilted.text

        optics(sim_rig, "cam1", pitch_deg=0.0)
        assert check(cam, mapped, reference=reference).state == "good"


def test_optics_control_refuses_bad_values_and_changes_nothing(sim_rig):
    assert optics(sim_rig, "cam2", yaw_deg=1.0)[0] == 200
    code, body = optics(sim_rig, "cam2", focus_blur_px=-1, yaw_deg=5.0)
    assert code == 400 and "focus_blur_px" in body["error"]
    code, body = optics(sim_rig, "cam2", zoom=2)
    assert code == 400 and "unknown optics setting 'zoom'" in body["error"]
    got = requests.get(f"http://127.0.0.1:{sim_rig.servers['cam2'].port}/sim/optics", timeout=10).json()
    assert got == {"focus_blur_px": 0.0, "yaw_deg": 1.0, "pitch_deg": 0.0}


def test_a_lens_in_focus_costs_the_renderer_nothing(sim_rig):
    """Focus 0 draws exactly what the renderer drew before it had a focus; a blur is another
    cached picture, and setting it back gives the first again from the cache."""
    r, t = sim_rig.renderer, sim_rig.clock.now()
    sharp = r.clean("cam1", t, led=True).copy()
    sim_rig.sources["cam1"].set_optics(focus_blur_px=2.0)
    soft = r.clean("cam1", t, led=True)
    assert np.abs(soft - sharp).max() > 50 and abs(float(soft.sum()) - float(sharp.sum())) < 1e-3 * sharp.sum()
    sim_rig.sources["cam1"].set_optics(focus_blur_px=0.0)
    hits = r.stats["hits"]
    assert np.array_equal(r.clean("cam1", t, led=True), sharp) and r.stats["hits"] == hits + 1


def test_fov_lands_where_the_mapping_says(sim_rig, mapped):
    """SPECT points projected through the calibration and mapping land on the scene's true
    projection of them (the scene's world frame is the SPECT frame), and the overlay draws the
    FOV centre there."""
    view, why = room_view(mapped, "cam1", (640, 480))
    assert why == "" and view is not None
    truth = sim_rig.scene.camera_at("cam1", sim_rig.scene.start_epoch)
    pts = np.array([[0.0, 0.0, 0.0], [120.0, -80.0, 150.0], [-200.0, 100.0, -180.0]])
    uv, front = view.project(pts)
    assert front.all() and np.abs(uv - truth.project(pts)).max() < 0.05
    with open_camera(mapped.camera("cam1")) as cam:
        verdicts, png = aim_page(cam, mapped)
    json.dumps(verdicts)  # JSON-able, for a page
    assert png.startswith(b"\x89PNG") and verdicts["camera"] == "cam1"
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    x, y = np.round(uv[0]).astype(int)
    patch = img[y - 3 : y + 4, x - 3 : x + 4].reshape(-1, 3).astype(int)
    assert (np.abs(patch - COLOURS["fov"]).sum(axis=1) < 40).any(), "no FOV cross at the FOV centre"
    assert {i["item"]: i["state"] for i in verdicts["items"]}["gantry"] == "good"


def test_without_a_mapping_the_fov_is_not_known(sim_rig):
    cfg = sim_rig.config()
    with open_camera(cfg.camera("cam2")) as cam:
        report = check(cam, cfg)
    fov, gantry = report.item("fov"), report.item("gantry")
    assert fov.state == gantry.state == "unknown"
    assert fov.text == "not known: no mapping" and report.state == "good"
    assert report.unknown == ["fov", "gantry"]
