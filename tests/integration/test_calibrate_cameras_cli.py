"""`vts calibrate cameras`: real pairs as the N = 2 case, image naming, the simulated four-camera
room against its truth, view graphs refused in one sentence."""

import json

import pytest

from inprocess_cli import run
from vts_hw.vision.calibration_io import CameraCalibration, load_calibration


def vts(*args, cwd, command="cameras"):
    """`vts calibrate COMMAND ARGS` in this process (tests/inprocess_cli.py), from the folder ``cwd``."""
    return run("calibrate", command, *args, cwd=cwd)


@pytest.fixture(scope="module")
def boards(shared_data):
    return shared_data / "stereo-checkerboard"


@pytest.fixture(scope="module")
def stereo(boards, tmp_path_factory):
    """`vts calibrate stereo` on the real pairs: plain OpenCV's figures (tests/unit/test_calibration.py)."""
    tmp = tmp_path_factory.mktemp("stereo")
    r = vts(boards, "--json", "-o", tmp / "s.json", cwd=tmp, command="stereo")
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def _link(src, dst):
    dst.parent.mkdir(parents=True, exist_ok=True)
    dst.symlink_to(src)


def test_real_pairs_equal_the_stereo_calibration(boards, stereo, tmp_path):
    out = tmp_path / "cal.json"
    r = vts(boards, "--json", "-o", out, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["n_cameras"] == 2 and [c["name"] for c in d["cameras"]] == ["left", "right"]
    assert d["rms"] == pytest.approx(stereo["rms"], rel=0.01)
    baseline = sum(x * x for x in stereo["cameras"][1]["t"]) ** 0.5  # camera 1 is the frame
    assert load_calibration(out).baseline == pytest.approx(baseline, rel=0.005)
    assert d["outliers"] == ["02"] and d["view_graph"]["connected"] and "change" not in d
    # stored as a run: no rig config here, so the per-user store and an empty rig name
    from vts_hw.store import ResultsStore

    with ResultsStore(None) as store:
        run = store.run(d["stored"]["run_id"])
        got = {(m.subject, m.metric): m.value for m in store.measurements(run_id=run.id)}
    assert (run.procedure, run.rig, run.status) == ("calibration", "", "OK")  # one name, as stereo's
    assert got == {
        ("left", "calibration_rms_px"): pytest.approx(d["cameras"][0]["rms"]),
        ("right", "calibration_rms_px"): pytest.approx(d["cameras"][1]["rms"]),
        ("set", "calibration_rms_px"): pytest.approx(d["rms"]),
        ("set", "calibration_converged"): 1.0,
    }
    # a second run reports the change from the file it replaces
    r = vts(boards, "-o", out, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert f"Change from the previous calibration {out} (cameras matched by name):" in r.stdout
    assert "every change is within 3 combined standard deviations" in r.stdout
    assert "View graph: connected" in r.stdout and "left - right: 13 shared view(s)" in r.stdout


@pytest.mark.parametrize("layout", ["folders", "names"])
def test_image_names_and_folders(boards, tmp_path, layout):
    """One folder per camera, or <camera>_<view> files: the same calibration as the stereo names."""
    for i in (1, 3, 4, 5, 6, 7):
        for side, cam in (("left", "head"), ("right", "foot")):
            name = f"{cam}/{i:02d}.jpg" if layout == "folders" else f"imgs/{cam}_{i:02d}.jpg"
            _link(boards / f"{side}{i:02d}.jpg", tmp_path / "in" / name)
    args = [tmp_path / "in"] if layout == "folders" else sorted((tmp_path / "in" / "imgs").iterdir())
    r = vts(*args, "--json", "-o", tmp_path / "cal.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert sorted(c["name"] for c in d["cameras"]) == ["foot", "head"]
    assert sorted(d["view_graph"]["views"]) == ["01", "03", "04", "05", "06", "07"]


def test_sim_four_cameras_against_the_truth(tmp_path):
    """The reference room of 4 cameras: pairs at the head and the foot end, facing each other."""
    from vts_hw.sim_devices.scene import Scene

    scene = Scene.reference(0, n_cameras=4, start_epoch=0.0)
    head = {n for n, c in scene.cameras.items() if c.center[2] < 0}
    assert head == {"cam1", "cam2"} and all(scene.cameras[n].center[2] > 0 for n in ("cam3", "cam4"))
    out = tmp_path / "sim.json"
    r = vts("--sim", "--cameras", 4, "--sim-poses", 5, "--json", "-o", out, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["n_cameras"] == 4 and d["unit"] == "mm" and d["view_graph"]["connected"]
    assert max(len(c) for c in d["view_graph"]["views"].values()) == 2  # no view needs all four
    across = [p for p in d["sim"]["pairs"] if len(head & set(p["cameras"])) == 1]
    assert across, d["sim"]["pairs"]  # boards seen by a head and a foot camera
    assert d["adjustment"]["converged"], d["adjustment"]
    assert d["warnings"] == [] and r.stderr == ""
    # measured (seed 0, 5 poses per pair): RMS 0.09 px; about 1.5 mm in camera 1's frame (the
    # scale along the view), 0.03 mm after the best rigid fit (before the head-and-foot board
    # plan: 200 evaluations without converging, RMS 2.4 px, 228 mm and 2.9 mm)
    assert d["rms"] < 0.15
    p = d["sim_truth"]["points_3d"]
    assert p["unit"] == "mm" and p["n"] > 300
    assert 0 < p["rms"] < 25 and p["rms_after_rigid_fit"] < 0.1
    assert set(d["sim_truth"]["cameras"]) == {"cam1", "cam2", "cam3", "cam4"}
    for rows in d["sim_truth"]["cameras"].values():
        assert abs(rows["fx"]["error_percent"]) < 0.5 and rows["rotation_error_deg"] < 0.5
    assert isinstance(load_calibration(out), CameraCalibration)


def _views(boards, tmp_path, plan):
    """Symlinks <camera>_<view>.jpg from the real images: plan = camera -> (side, views)."""
    files = []
    for cam, (side, views) in plan.items():
        for i in views:
            files.append(tmp_path / "in" / f"{cam}_{i:02d}.jpg")
            _link(boards / f"{side}{i:02d}.jpg", files[-1])
    return files


@pytest.mark.parametrize(
    "plan, words",
    [
        (
            {
                "cam1": ("left", (1, 3, 4)),
                "cam2": ("right", (1, 3, 4)),
                "cam3": ("left", (5, 6, 7)),
                "cam4": ("right", (5, 6, 7)),
            },
            "the checkerboard views do not connect the cameras: cam1, cam2 | cam3, cam4 share no view across the groups",
        ),
        (
            {"cam1": ("left", (1, 3, 4)), "cam2": ("right", (1, 3, 4)), "cam3": ("left", (5, 6, 7))},
            "camera cam3 found the board in no view that another camera also saw",
        ),
    ],
)
def test_view_graphs_refused_in_one_sentence(boards, tmp_path, plan, words):
    r = vts(*_views(boards, tmp_path, plan), "-o", tmp_path / "out.json", cwd=tmp_path)
    assert r.returncode == 3 and r.stdout == ""
    assert r.stderr.startswith(f"vts: {words}") and r.stderr.count("\n") == 1
    assert not (tmp_path / "out.json").exists()


def test_bad_inputs(boards, tmp_path):
    (tmp_path / "photo.jpg").write_bytes(b"x")
    r = vts(tmp_path / "photo.jpg", cwd=tmp_path)
    assert r.returncode == 3 and "image names must be <camera>_<view>.jpg" in r.stderr
    assert "Traceback" not in r.stderr and r.stderr.count("\n") == 1
    assert vts(cwd=tmp_path).returncode == 2
    assert vts("--sim", boards, cwd=tmp_path).returncode == 2
    r = vts(boards, "--reference", "cam9", "-o", tmp_path / "o.json", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr == (
        "vts: the reference camera 'cam9' is not among the cameras of the images: left, right.\n"
    )
    r = vts(tmp_path / "missing", cwd=tmp_path)
    assert r.returncode == 3 and r.stderr == f"vts: {tmp_path / 'missing'}: no such file or directory.\n"


def test_help_says_how_images_are_named(tmp_path):
    r = vts("--help", cwd=tmp_path)
    assert "<camera>_<view>.jpg" in r.stdout and "one folder per" in r.stdout


def test_stereo_and_n_camera_files_replace_and_compare_with_each_other(boards, tmp_path):
    from pathlib import Path

    out = tmp_path / "calibration.json"
    old = Path(__file__).parents[1] / "data" / "calibration-stereo-v1.json"  # as `stereo` wrote it before
    out.write_bytes(old.read_bytes())
    r = vts(boards, "-o", out, cwd=tmp_path)  # N cameras over an old stereo file
    assert r.returncode == 0, r.stderr
    assert "(cameras matched by order (a stereo file)):" in r.stdout
    assert isinstance(load_calibration(out), CameraCalibration)
    r = vts(boards, "-o", out, cwd=tmp_path, command="stereo")  # and the pair over N cameras
    assert r.returncode == 0, r.stderr
    assert f"Change from the previous calibration {out}" in r.stdout
    assert "rotation between cameras changed by" in r.stdout  # judged as a pair
    assert load_calibration(out).pair is not None
    r = vts(boards, "-o", out, cwd=tmp_path)  # N cameras over the pair: one kind of file
    assert r.returncode == 0, r.stderr
    assert "(cameras matched by name):" in r.stdout


def test_a_fit_that_did_not_converge_is_not_saved(tmp_path, monkeypatch, capsys):
    """A bundle adjustment stopped before it converged: a WARNING line, -o not written, exit 3;
    --force writes it (exit 0), the file saying it did not converge."""
    import functools

    from vts_hw.cli import main
    from vts_hw.vision import bundle

    monkeypatch.setattr(bundle, "adjust", functools.partial(bundle.adjust, max_nfev=1))
    out = tmp_path / "cal.json"
    args = ["calibrate", "cameras", "--sim", "--cameras", "2", "--sim-poses", "4", "-o", str(out)]
    with pytest.raises(SystemExit) as e:
        main(args)
    assert e.value.code == 3
    o, err = capsys.readouterr()
    assert "WARNING: the bundle adjustment did not converge (1 evaluations" in o
    assert err.count("\n") == 1 and err.startswith(f"vts: {out} was not written, the fit cannot be trusted:")
    assert err.rstrip().endswith("give --force to write it anyway.") and "Traceback" not in err
    assert not out.exists()
    main([*args, "--force", "--json"])
    o, err = capsys.readouterr()
    assert json.loads(o)["adjustment"]["converged"] is False
    assert "WARNING: the bundle adjustment did not converge" in err
    assert load_calibration(out).adjustment["converged"] is False
