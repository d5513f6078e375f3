"""`vts calibrate spect`: the simulated session against the truth, files, bad inputs."""

import json

import numpy as np
import pytest

from inprocess_cli import run
from vts_hw.sim_devices.spect import SimSpect, phantom_centres
from vts_hw.vision.registration import RigidTransform


def vts(*args, cwd):
    """`vts calibrate spect ARGS` in this process (tests/inprocess_cli.py), from the folder ``cwd``."""
    return run("calibrate", "spect", *args, cwd=cwd)


def test_sim_json_against_truth(tmp_path):
    out = tmp_path / "map.json"
    r = vts("--sim", "--json", "-o", out, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["n_spheres"] == 7 and d["output"] == str(out)
    assert d["fre_mm"] < 0.5
    assert "true camera models" in d["sim"]["calibration"]
    # measured (seeds 0-3): rotation 0.006-0.02 deg, translation at the phantom 0.01-0.02 mm
    assert d["sim_truth"]["rotation_error_deg"] < 0.1
    assert d["sim_truth"]["translation_error_at_phantom_mm"] < 0.3
    T = RigidTransform.load(out)
    assert np.allclose(T.R, d["transform"]["R"]) and np.allclose(T.t, d["transform"]["t_mm"])
    assert np.allclose(T.R, d["sim_truth"]["true_transform"]["R"], atol=1e-3)


def test_sim_text(tmp_path):
    r = vts("--sim", "--sim-seed", "1", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "as if perfectly calibrated" in r.stdout
    assert "Compared with the simulated truth" in r.stdout
    assert (tmp_path / "spect_mapping.json").exists()


@pytest.fixture()
def session(tmp_path):
    """Known VTS points (a rigid motion of the true centres) and a SimSpect volume of them."""
    spect = phantom_centres()
    truth = RigidTransform.from_euler_xyz_deg([5.0, -10.0, 30.0], [12.0, -40.0, 300.0])
    vts_pts = truth.inverse().apply(spect)
    volume = SimSpect(seed=7).write(tmp_path / "phantom.npz", spect)
    return vts_pts, volume, truth


def test_files_csv(tmp_path, session):
    vts_pts, volume, truth = session
    csv = tmp_path / "vts.csv"
    csv.write_text("x,y,z\n" + "".join(f"{x:.4f},{y:.4f},{z:.4f}\n" for x, y, z in vts_pts[::-1]))
    r = vts("--vts", csv, "--volume", volume, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "FRE (RMS fit residual)" in r.stdout and "leave-one-out TRE" in r.stdout
    T = RigidTransform.load(tmp_path / "spect_mapping.json")
    assert np.linalg.norm(T.apply(vts_pts) - truth.apply(vts_pts), axis=1).max() < 1.5
    # the volume that places the SPECT frame is kept with the mapping (CASToR's centre: decision 0043)
    vol = T.meta["spect_volume"]
    assert vol["file"] == "phantom.npz" and vol["format"] == "npz" and vol["shape"] == [64, 64, 64]
    assert np.allclose(vol["centre_mm"], 0.0, atol=1e-9)  # SimSpect centres its FOV on the origin


def test_files_json(tmp_path, session):
    vts_pts, volume, _ = session
    pts = tmp_path / "vts.json"
    pts.write_text(json.dumps(vts_pts.tolist()))
    out = tmp_path / "m.json"
    r = vts("--vts", pts, "--volume", volume, "-o", out, "--json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert data["fre_mm"] < 2.0 and data["state"] == "OK"
    RigidTransform.load(out)
    # stored as a run, the one way every QA result is (no rig config: the per-user store)
    from vts_hw.store import ResultsStore

    with ResultsStore(None) as store:
        run = store.run(data["stored"]["run_id"])
        ms = {m.metric: m.value for m in store.measurements(run_id=run.id)}
    assert run.procedure == "spect_mapping" and run.status == "OK"
    assert ms == {
        "mapping_fre_mm": pytest.approx(data["fre_mm"]),
        "mapping_tre_rms_mm": pytest.approx(data["tre_rms_mm"]),
    }


@pytest.mark.parametrize("text", ["a,b,c\n1,2,3\n", "x,y,z\n1,2,oops\n", ""])
def test_bad_csv(tmp_path, session, text):
    _, volume, _ = session
    csv = tmp_path / "bad.csv"
    csv.write_text(text)
    r = vts("--vts", csv, "--volume", volume, cwd=tmp_path)
    assert r.returncode == 3, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and r.stderr.startswith("vts: ")
    assert str(csv) in r.stderr
    assert not (tmp_path / "spect_mapping.json").exists()


def test_missing_volume(tmp_path, session):
    vts_pts, _, _ = session
    csv = tmp_path / "vts.csv"
    csv.write_text("x,y,z\n" + "".join(f"{x},{y},{z}\n" for x, y, z in vts_pts))
    r = vts("--vts", csv, "--volume", tmp_path / "nope.npz", cwd=tmp_path)
    assert r.returncode == 3, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "nope.npz" in r.stderr


def test_wrong_sphere_count(tmp_path, session):
    vts_pts, volume, _ = session
    csv = tmp_path / "vts.csv"
    csv.write_text("x,y,z\n" + "".join(f"{x},{y},{z}\n" for x, y, z in vts_pts[:5]))
    r = vts("--vts", csv, "--volume", volume, cwd=tmp_path)
    assert r.returncode == 3, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_usage(tmp_path):
    assert vts(cwd=tmp_path).returncode == 2
    assert vts("--sim", "--vts", "x.csv", cwd=tmp_path).returncode == 2


@pytest.mark.parametrize(
    "n_cameras, calibrate", [(2, ["stereo"]), (4, ["cameras", "--cameras", "4"])], ids=["stereo pair", "four cameras"]
)
def test_from_cameras_on_a_live_simulated_rig(tmp_path, n_cameras, calibrate):
    """The real-rig path: the rig's cameras over HTTP, a calibration from rendered
    checkerboards (a stereo pair, or N cameras: then every calibrated camera measures, and the
    mapping names them), a SPECT volume of the phantom; the spheres picked out by shape."""
    import os

    from vts_hw.sim_devices.rig import SimRig
    from vts_hw.sim_devices.step_table import sphere_centres
    from vts_hw.vision.registration import difference

    cal = tmp_path / "cal.json"
    r = run("calibrate", *calibrate, "--sim", "--sim-seed", "2", "-o", cal)
    assert r.returncode == 0, r.stderr
    with SimRig(n_cameras=n_cameras, seed=2) as rig:
        rig.scene.add_phantom()
        cfg, _ = rig.write(tmp_path / "rig")
        vol = SimSpect(seed=2).write(tmp_path / "phantom.npz", sphere_centres(rig.scene, rig.clock.now()))
        out = tmp_path / "map.json"
        env = {**os.environ, **rig.env_vars()}
        r = run(
            "calibrate",
            "spect",
            "--from-cameras",
            "--volume",
            vol,
            "--calibration",
            cal,
            "--config",
            cfg,
            "--frames",
            "4",
            "--json",
            "-o",
            out,
            env=env,
        )
        assert r.returncode == 0, r.stderr
        c1 = rig.scene.camera_at("cam1", rig.clock.now())
    d = json.loads(r.stdout)
    assert d["n_spheres"] == 7 and d["fre_mm"] < 0.5 and d["tre_rms_mm"] < 1.0
    assert d["vts_cameras"] == [f"cam{k + 1}" for k in range(n_cameras)]
    # against the truth: camera 1's true pose, up to the calibration's own small error
    truth = RigidTransform(c1.R.T, -c1.R.T @ c1.t)
    diff = difference(truth, RigidTransform.load(out))
    assert diff.angle_deg < 1.0


def test_from_cameras_needs_a_calibration(tmp_path):
    cfg = tmp_path / "rig.yaml"
    cfg.write_text("cameras:\n  - {name: cam1, host: 127.0.0.1, port: 9}\n  - {name: cam2, host: 127.0.0.1, port: 9}\n")
    vol = SimSpect(seed=0).write(tmp_path / "v.npz", phantom_centres())
    r = vts("--from-cameras", "--volume", vol, "--config", cfg, cwd=tmp_path)
    assert r.returncode == 2 and "calibration.cameras" in r.stderr and "Traceback" not in r.stderr


def test_disk_full_keeps_the_mapping(tmp_path, session, small_disk):
    """-o on a full disk: the sentence names the file, the previous mapping there is intact, the
    new one is saved in the current folder and reads back; nothing half-written."""
    vts_pts, volume, truth = session
    csv = tmp_path / "vts.csv"
    csv.write_text("x,y,z\n" + "".join(f"{x},{y},{z}\n" for x, y, z in vts_pts))
    disk = small_disk(64)
    out = disk.path / "spect_mapping.json"
    assert vts("--vts", csv, "--volume", volume, "-o", out, cwd=tmp_path).returncode == 0
    before = out.read_bytes()
    disk.fill()
    r = vts("--vts", csv, "--volume", volume, "-o", out, cwd=tmp_path)
    assert r.returncode == 3
    assert "FRE (RMS fit residual)" in r.stdout and "wrote" not in r.stdout
    saved = list(tmp_path.glob("spect_mapping-*.json"))
    assert len(saved) == 1
    assert r.stderr == (
        f"vts: {out}: could not be written (no space left on device); the previous"
        f" version is unchanged; the mapping was saved to {saved[0]} instead\n"
    )
    T = RigidTransform.load(saved[0])
    assert np.linalg.norm(T.apply(vts_pts) - truth.apply(vts_pts), axis=1).max() < 1.5
    assert out.read_bytes() == before and disk.files() == {"spect_mapping.json": len(before)}


@pytest.mark.parametrize("doc", ["[" * 5000, "[[1, 2, " + "9" * 400 + "]]", "[[1, 2, 1" + "0" * 5000 + "]]"])
def test_a_points_file_json_beyond_syntax_is_a_data_error(tmp_path, doc):
    from vts_hw.errors import DataError
    from vts_hw.procedures.mapping_points import read_points

    p = tmp_path / "pts.json"
    p.write_text(doc)
    with pytest.raises(DataError, match="pts.json"):
        read_points(p)


def test_the_cameras_a_calibration_covers(tmp_path):
    """Which of a rig's cameras to open: all the N-camera file names, the first two for a
    stereo file or a file named after its images."""
    from vts_hw.config import load_rig
    from vts_hw.errors import ConfigError
    from vts_hw.procedures.mapping_inputs import calibrated_cameras
    from vts_hw.vision.triangulate import PinholeCamera

    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        "cameras:\n"
        + "".join(f"  - {{name: {n}, host: 127.0.0.1, port: 9}}\n" for n in ("head-l", "head-r", "foot-l", "foot-r"))
    )
    rig = load_rig(cfg)

    def cams(*names):
        return [PinholeCamera(np.eye(3), np.zeros(5), np.eye(3), np.zeros(3), n) for n in names]

    names = lambda calib: [c.name for c in calibrated_cameras(rig, calib)]  # noqa: E731
    assert names(cams("foot-r", "head-l", "foot-l")) == ["head-l", "foot-l", "foot-r"]
    assert names(cams("IMG_a", "IMG_b", "IMG_c")) == ["head-l", "head-r", "foot-l"]
    assert names(cams("", "")) == ["head-l", "head-r"]
    with pytest.raises(ConfigError, match="covers 1 of the rig's cameras"):
        calibrated_cameras(rig, cams("foot-l"))


def test_an_output_that_is_not_a_mapping_is_refused_before_the_work(tmp_path, session):
    """`-o rig.yaml` by mistake: refused in one sentence, the file byte-identical; --force
    replaces it; an earlier mapping there is replaced without asking."""
    vts_pts, volume, _ = session
    csv = tmp_path / "vts.csv"
    csv.write_text("x,y,z\n" + "".join(f"{x},{y},{z}\n" for x, y, z in vts_pts))
    cfg = tmp_path / "rig.yaml"
    cfg.write_text("rig: room1\ncameras:\n  - {name: cam1, host: 127.0.0.1}\n")
    before = cfg.read_bytes()
    r = vts("--vts", csv, "--volume", volume, "-o", cfg, cwd=tmp_path)
    assert r.returncode == 3 and r.stderr == (
        f"vts: {cfg} exists and is not a VTS → SPECT mapping file;"
        " give another -o, move it away, or give --force to replace it.\n"
    )
    assert "FRE" not in r.stdout and cfg.read_bytes() == before
    assert not list(tmp_path.glob("spect_mapping*"))
    out = tmp_path / "m.json"
    assert vts("--vts", csv, "--volume", volume, "-o", out, cwd=tmp_path).returncode == 0
    assert vts("--vts", csv, "--volume", volume, "-o", out, cwd=tmp_path).returncode == 0  # a mapping: replaced
    r = vts("--vts", csv, "--volume", volume, "-o", cfg, "--force", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    RigidTransform.load(cfg)
