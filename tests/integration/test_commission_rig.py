"""`vts commission` points rig.yaml's `calibration:` at what it made (decision 0069): a calibration
step that passed sets `calibration.cameras`, a mapping that passed `calibration.mapping`, in place
(comments kept, rig.yaml.bak, atomic), so that `vts camera aim` and every later command use them;
a step that did not pass changes nothing; rig.yaml that cannot be written is one sentence, the
new file kept, the commissioning resumable. On the simulated rig, its cameras over HTTP."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import pytest

from inprocess_cli import vts
from vts_hw.config import dump_rig, load_rig
from vts_hw.errors import UsageError
from vts_hw.files import WriteFailed
from vts_hw.rig_file import set_calibration
from vts_hw.sim_devices import checkerboard as cb
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.spect import SimSpect
from vts_hw.sim_devices.step_table import SPECT_MATRIX, sphere_centres
from vts_hw.sim_devices.sync_truth import write_true_calibration
from vts_hw.store import ResultsStore
from vts_hw.store.commission import load_state

HEAD = "# room 1: the cameras over the table (written by hand)\n"
CAL_COMMENT = "calibration:   # the files of the last calibration\n"


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """The simulated rig with the phantom on the table, the operator's checkerboard views of it,
    the SPECT's reconstruction of the phantom, and the scene's true calibration files (the
    "old" ones rig.yaml names before commissioning)."""
    d = tmp_path_factory.mktemp("room")
    rig = SimRig(n_cameras=2, seed=4).start()
    try:
        rig.scene.add_phantom()
        pairs, names = cb.render_pairs(rig.scene, n=12, seed=1, t=rig.clock.now())
        for (left, right), name in zip(pairs, names):
            for cam, img in (("cam1", left), ("cam2", right)):
                (d / "boards" / cam).mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(d / "boards" / cam / f"{name}.png"), img)
        phantom = SimSpect(matrix=SPECT_MATRIX, seed=7).write(
            d / "phantom.npz", sphere_centres(rig.scene, rig.clock.now())
        )
        truth = write_true_calibration(rig.scene, d / "truth")
        with rig.env():
            yield rig, d / "boards", phantom, truth
    finally:
        rig.stop()


def _rig_yaml(rig, truth, folder: Path, store: Path, extra: str = "") -> tuple[Path, Path, Path]:
    """rig.yaml in ``folder`` naming copies of the true calibration files (old/), with comments."""
    (folder / "old").mkdir(parents=True, exist_ok=True)
    old_cal, old_map = (Path(shutil.copy(f, folder / "old" / Path(f).name)) for f in truth)
    text = dump_rig(
        rig.config(
            rig_name="room1",
            results_url=f"sqlite:///{store}",
            calibration={"stereo": str(old_cal), "spect": str(old_map)},
        )
    )
    assert text.count("calibration:\n") == 1
    y = folder / "rig.yaml"
    y.write_text(HEAD + text.replace("calibration:\n", CAL_COMMENT) + extra)
    return y, old_cal, old_map


def _commission(capsys, y, out, boards, phantom, *more):
    return vts(
        capsys,
        "commission",
        "--config",
        y,
        "-o",
        out,
        "--frames",
        "2",
        "--checkerboards",
        boards,
        "--square",
        cb.SQUARE_MM,
        "--phantom-volume",
        phantom,
        *more,
    )


def _fov(capsys, config: Path) -> dict:
    code, so, se = vts(capsys, "camera", "aim", "cam1", "--once", "--json", "--config", config)
    assert code in (0, 10), se
    return next(i for i in json.loads(so)["items"] if i["item"] == "fov")


def _without_paths(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if not ln.lstrip().startswith(("cameras:", "mapping:", "stereo:", "spect:"))]


def test_a_commissioning_points_rig_yaml_at_its_calibration_and_mapping(room, tmp_path, capsys):
    rig, boards, phantom, truth = room
    y, old_cal, old_map = _rig_yaml(rig, truth, tmp_path, tmp_path / "r.sqlite")
    before = y.read_text()
    out = tmp_path / "commission"
    cal, mp = out / "calibration.json", out / "spect_mapping.json"

    code, so, se = _commission(capsys, y, out, boards, phantom, "--from", "calibration")
    assert code == 2 and "the step test needs --step-volumes DIR" in se, se  # stopped after the mapping
    assert f"rig.yaml now points at {cal} (calibration.cameras; the previous text is in {y}.bak)" in se
    assert f"rig.yaml now points at {mp} (calibration.mapping; the previous text is in {y}.bak)" in se
    now = load_rig(y).calibration
    assert (now.cameras, now.mapping) == (cal, mp) and cal.is_file() and mp.is_file()
    text = y.read_text()
    assert text.startswith(HEAD) and CAL_COMMENT in text  # the comments kept
    assert _without_paths(text) == _without_paths(before)  # and nothing else changed
    bak = Path(f"{y}.bak")
    assert load_rig(bak).calibration.cameras == cal and load_rig(bak).calibration.mapping == old_map
    assert bak.read_text().startswith(HEAD)  # the text before the last write

    with ResultsStore(f"sqlite:///{tmp_path / 'r.sqlite'}") as store:
        steps = load_state(store, "room1").steps
        assert steps["calibration"].passed and steps["mapping"].passed
        assert f"rig.yaml now points at {cal}" in steps["calibration"].notes  # the report's notes column
        assert f"rig.yaml now points at {mp}" in steps["mapping"].notes

    # `vts camera aim` reads the new files: with the old ones gone, rig.yaml.bak (the old mapping)
    # cannot place the SPECT FOV; rig.yaml can
    old_cal.unlink()
    old_map.unlink()
    assert _fov(capsys, bak)["state"] == "unknown"
    fov = _fov(capsys, y)
    assert fov["state"] in ("good", "adjust") and fov["value"] is not None, fov

    # the mapping again: rig.yaml names that file already, so nothing is written
    stamp, bak_text = y.stat().st_mtime_ns, bak.read_text()
    code, so, se = _commission(capsys, y, out, boards, phantom, "--from", "mapping")
    assert code == 2 and f"rig.yaml already points at {mp} (calibration.mapping)" in se, se
    assert y.stat().st_mtime_ns == stamp and y.read_text() == text and bak.read_text() == bak_text


def test_a_mapping_in_action_leaves_the_spect_entry_as_it_was(room, tmp_path, capsys):
    rig, boards, phantom, truth = room
    strict = "tolerances: {mapping_fre_mm: {tolerance_high: 0.0001, action_high: 0.0002, unit: mm}}\n"
    y, old_cal, old_map = _rig_yaml(rig, truth, tmp_path, tmp_path / "r.sqlite", strict)
    before = y.read_text()
    out = tmp_path / "commission"
    out.mkdir()
    shutil.copy(truth[0], out / "calibration.json")  # a calibration made before: the mapping's input
    code, so, se = _commission(capsys, y, out, boards, phantom, "--from", "mapping")
    assert code == 20, se
    assert "commissioning stopped at VTS → SPECT mapping: the mapping is in ACTION" in so
    assert (out / "spect_mapping.json").is_file()  # saved, as `vts calibrate spect` saves it
    assert y.read_text() == before and not Path(f"{y}.bak").exists()
    assert "now points at" not in se
    assert load_rig(y).calibration.mapping == old_map


def test_rig_yaml_on_a_read_only_folder_is_one_sentence_keeps_the_calibration_and_goes_on(
    room, tmp_path, capsys, small_disk
):
    rig, boards, phantom, truth = room
    disk = small_disk(512)
    y, old_cal, _ = _rig_yaml(rig, truth, disk.path, tmp_path / "r.sqlite")
    before = y.read_text()
    out = tmp_path / "commission"
    cal = out / "calibration.json"
    disk.read_only()
    code, so, se = _commission(capsys, y, out, boards, phantom, "--from", "calibration")
    last = se.strip().splitlines()[-1]
    assert code == 3, se
    assert last == (
        f"vts: {y}.bak: could not be written (read-only file system); {y} is unchanged "
        f"(calibration.cameras: {old_cal}); the new calibration is kept in {cal}: "
        f"`vts commission --from calibration` once {y} can be written"
    ), se
    assert "Traceback" not in se and y.read_text() == before and not Path(f"{y}.bak").exists()
    assert json.loads(cal.read_text())  # the calibration kept, whole
    with ResultsStore(f"sqlite:///{tmp_path / 'r.sqlite'}") as store:
        s = load_state(store, "room1").steps["calibration"]
        assert not s.passed and "could not be written" in s.notes
        assert store.run(s.step_run).procedure == "calibration"  # its figures stored all the same

    disk.read_only(False)  # the folder writable again: as it says
    code, so, se = _commission(capsys, y, out, boards, phantom, "--from", "calibration")
    assert code == 2 and "== calibration" in se and f"rig.yaml now points at {cal}" in se, se
    now = load_rig(y).calibration
    assert (now.cameras, now.mapping) == (cal, out / "spect_mapping.json")
    assert _without_paths(y.read_text()) == _without_paths(before) and y.read_text().startswith(HEAD)


def test_set_calibration_on_a_full_disk_or_a_file_changed_meanwhile_writes_nothing(tmp_path, small_disk, monkeypatch):
    disk = small_disk(256)
    y = disk.path / "rig.yaml"
    y.write_text(HEAD + "rig: r\ncameras:\n- name: cam1\n  host: 127.0.0.1\n  port: 80\n")
    disk.fill()
    with pytest.raises(
        WriteFailed,
        match=r"rig\.yaml\.bak: could not be written \(no space left on device\); "
        r".*rig\.yaml is unchanged",
    ):
        set_calibration(y, {"cameras": tmp_path / "c.json"})
    assert y.read_text().startswith(HEAD) and sorted(disk.files()) == ["rig.yaml"]
    disk.free_up()

    import vts_hw.rig_file as rf

    reads = []

    def read(p):
        reads.append(p)
        return Path(p).read_text() + ("# someone else\n" if len(reads) > 1 else "")

    monkeypatch.setattr(rf, "_read_text", read)
    with pytest.raises(UsageError, match="was changed while its calibration paths were being set: it is left as it is"):
        set_calibration(y, {"cameras": tmp_path / "c.json"})
    assert "calibration" not in y.read_text() and sorted(disk.files()) == ["rig.yaml"]
    monkeypatch.undo()  # a relative file name: written as the absolute path (every reader's same file)
    monkeypatch.chdir(tmp_path)
    set_calibration(y, {"mapping": "m.json"})
    assert load_rig(y).calibration.mapping == tmp_path / "m.json" and f"mapping: {tmp_path / 'm.json'}" in y.read_text()
