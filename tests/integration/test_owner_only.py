"""Files holding secrets are readable by their owner only (issue 32 §1 "Durable audit", decision
0081), each created as it is in use, under umask 022 (the usual one, which makes 0644 files):
the results store (the console users' password hashes) with its -wal and -shm, an unsaved run,
the simulated rig's sim.env (camera passwords, the QATrack+ token) and its TLS key. A file a
writer replaces keeps its own mode: a rewrite never widens what its owner chose."""

from __future__ import annotations

import os
import shutil
import stat

import pytest

from vts_hw.files import WriteFailed, write_atomic
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.tls import self_signed
from vts_hw.store import ResultsStore
from vts_hw.store.unsaved import save_unsaved


def mode(path) -> int:
    return stat.S_IMODE(os.lstat(path).st_mode)


@pytest.fixture()
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def test_a_new_store_its_wal_and_shm_and_its_folder_are_the_owners_only(tmp_path, umask_022):
    db = tmp_path / "vts-hw" / "results.sqlite"
    with ResultsStore(db) as store:
        store.put_user("alice", "physicist", "scrypt$a-password-hash")  # what makes it a secret
        assert (db.parent / "results.sqlite-wal").exists()  # while it is open
        assert {p.name: mode(p) for p in db.parent.iterdir()} == {
            "results.sqlite": 0o600,
            "results.sqlite-wal": 0o600,
            "results.sqlite-shm": 0o600,
        }
    assert mode(db.parent) == 0o700


def test_a_store_of_ours_that_others_could_read_is_narrowed_when_opened(tmp_path, umask_022):
    db = tmp_path / "results.sqlite"
    ResultsStore(db).close()
    os.chmod(db, 0o644)  # as vts-hw made them before
    ResultsStore(db, mode="read").close()
    assert mode(db) == 0o600


def test_an_unsaved_run_is_the_owners_only(tmp_path, umask_022):
    path, _ = save_unsaved(
        f"sqlite:///{tmp_path / 'store' / 'results.sqlite'}", {"procedure": "drift", "started": 1.0, "measurements": []}
    )
    assert path is not None and path.parent == tmp_path / "store" / "unsaved" and mode(path) == 0o600


def test_an_unsaved_run_that_the_full_disk_refused_leaves_no_empty_folder(tmp_path, small_disk, monkeypatch):
    """Found by the sweep's console full disk class: a run the store on a full disk did not take
    went elsewhere, and left an empty unsaved/ beside the store, a folder where runs seem to wait."""
    disk = small_disk(64)
    (disk.path / "store").mkdir()
    disk.fill()
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    path, tried = save_unsaved(
        f"sqlite:///{disk.path / 'store' / 'results.sqlite'}",
        {"procedure": "drift", "started": 1.0, "measurements": []},
    )
    assert path is not None and path.parent == tmp_path / "data" / "vts-hw" / "unsaved", (path, tried)
    assert tried and str(disk.path / "store" / "unsaved") in tried[0]
    assert not (disk.path / "store" / "unsaved").exists()


def test_sim_env_is_the_owners_only_and_an_old_wide_one_is_narrowed(tmp_path, umask_022):
    with SimRig(n_cameras=1, seed=1) as rig:
        folder = tmp_path / "sim"
        rig.write(folder)
        assert mode(folder / "sim.env") == 0o600 and mode(folder / "rig.yaml") == 0o644
        os.chmod(folder / "sim.env", 0o644)
        rig.write(folder)
    assert mode(folder / "sim.env") == 0o600


def test_sim_env_goes_into_no_folder_another_may_write(tmp_path, umask_022):
    folder = tmp_path / "shared"
    folder.mkdir()
    os.chmod(folder, 0o777)  # anyone may rename sim.env away and put theirs there
    with SimRig(n_cameras=1, seed=1) as rig, pytest.raises(WriteFailed, match="anyone may write into its folder"):
        rig.write(folder)
    assert not (folder / "sim.env").exists()


@pytest.mark.skipif(shutil.which("openssl") is None, reason="the simulated HTTPS cameras' key is made by openssl")
def test_the_simulated_cameras_tls_key_is_the_owners_only(tmp_path, umask_022):
    cert, key = self_signed(tmp_path / "sim")
    assert mode(key) == 0o600 and mode(cert) == 0o644
    assert sorted(p.name for p in (tmp_path / "sim").iterdir()) == sorted([cert.name, key.name])  # no temporary copy


def test_a_replaced_file_keeps_its_owners_mode(tmp_path, umask_022):
    """A private rig.yaml or calibration rewritten by vts stays private (it became 0644)."""
    p = tmp_path / "calibration.json"
    p.write_text("{}\n")
    os.chmod(p, 0o600)
    write_atomic(p, '{"new": 1}\n')
    assert mode(p) == 0o600
    write_atomic(tmp_path / "new.json", "{}\n")
    assert mode(tmp_path / "new.json") == 0o644
    if os.geteuid() == 0:  # root rewriting a user's file leaves it theirs, not root's
        os.chown(p, 12345, 12345)
        write_atomic(p, '{"again": 1}\n')
        assert (os.lstat(p).st_uid, os.lstat(p).st_gid, mode(p)) == (12345, 12345, 0o600)
