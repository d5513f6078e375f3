"""`vts camera aim` on the simulated rig, in this process: the table and the exit codes, the
overlay and verdicts written, a drift baseline read from the store for the aim, one-sentence
errors (unknown camera, a camera off the network), no mapping an item not known."""

import json

import pytest
import requests
import yaml

from inprocess_cli import vts


@pytest.fixture()
def rig_yaml(sim_rig, tmp_path):
    """rig.yaml as `vts sim up` writes it: the true calibration and mapping, its own store."""
    path, _ = sim_rig.write(tmp_path / "sim")
    return path


def test_once_good_writes_the_overlay_and_the_verdicts(capsys, rig_yaml, tmp_path, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    code, out, err = vts(capsys, "camera", "aim", "cam1", "--once", "--out", tmp_path / "o", "--config", rig_yaml)
    assert code == 0, err
    assert "cam1: GOOD" in out and "SPECT FOV" in out and "through the gantry" in out
    data = json.loads((tmp_path / "o" / "cam1-aim.json").read_text())
    assert data["state"] == "good" and len(data["items"]) == 8
    assert (tmp_path / "o" / "cam1-aim.png").read_bytes().startswith(b"\x89PNG")


def test_misaimed_against_the_drift_baseline_exits_10_and_says_which_way(capsys, sim_rig, rig_yaml):
    code, _, err = vts(
        capsys, "qa", "drift", "--set-baseline", "--camera", "cam2", "--frames", "1", "--config", rig_yaml
    )
    assert code == 0, err
    url = f"http://127.0.0.1:{sim_rig.servers['cam2'].port}/sim/optics"
    assert requests.post(url, json={"yaw_deg": -2.5}, timeout=10).ok  # turned 2.5° left
    code, out, err = vts(capsys, "camera", "aim", "cam2", "--json", "--config", rig_yaml)
    assert code == 10, err
    aim = {i["item"]: i for i in json.loads(out)["items"]}["aim"]
    assert aim["state"] == "adjust" and aim["text"].startswith("aim 2.5° right"), aim["text"]
    assert "drift baseline" in aim["text"]


def test_another_rooms_baseline_is_not_this_cameras(capsys, rig_yaml):
    """A store shared by rooms: another room's cam2 is another camera; its baseline is not used."""
    from qa_runs import baselines_now
    from vts_hw.config import load_rig
    from vts_hw.store import ResultsStore

    cfg = load_rig(rig_yaml)
    with ResultsStore(cfg.store.url) as store:
        baselines_now(cfg.model_copy(update={"rig": "another-room"}), store, frames=1)
    code, out, err = vts(capsys, "camera", "aim", "cam2", "--json", "--config", rig_yaml)
    aim = {i["item"]: i for i in json.loads(out)["items"]}["aim"]
    assert "no drift baseline to say whether markers left it" in aim["text"], aim["text"]


def test_unknown_camera_and_a_camera_off_the_network(capsys, sim_rig, rig_yaml, tmp_path):
    code, out, err = vts(capsys, "camera", "aim", "cam9", "--once", "--config", rig_yaml)
    assert code == 2 and err.strip() == "vts: no camera named 'cam9' in the rig config (known: cam1, cam2)"
    sim_rig.servers["cam1"].faults.offline = True
    code, out, err = vts(capsys, "camera", "aim", "cam1", "--once", "--out", tmp_path / "o2", "--config", rig_yaml)
    assert code == 4 and err.startswith("vts: ") and "cam1" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o2" / "cam1-aim.png").exists()


def test_no_mapping_is_an_item_not_known_not_an_error(capsys, rig_yaml, tmp_path, monkeypatch):
    data = yaml.safe_load(rig_yaml.read_text())
    data.pop("calibration")
    bare = tmp_path / "bare.yaml"
    bare.write_text(yaml.safe_dump(data))
    monkeypatch.setenv("COLUMNS", "200")
    code, out, err = vts(capsys, "camera", "aim", "cam1", "--once", "--config", bare)
    assert code == 0, err
    assert "not known: no mapping" in out and "cam1: GOOD; not known: fov, gantry" in out


def test_bad_aim_settings_in_rig_yaml_are_one_sentence(capsys, rig_yaml, tmp_path):
    data = yaml.safe_load(rig_yaml.read_text())
    data["aim"] = {"edge_width_max_px": -1}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    code, out, err = vts(capsys, "camera", "aim", "cam1", "--once", "--config", bad)
    assert code == 2 and "aim.edge_width_max_px" in err and len(err.strip().splitlines()) == 1
