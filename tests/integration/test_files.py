"""vts_hw.files: a file is written whole or not at all, on a real full disk and a read-only mount."""

import pytest

from vts_hw.errors import DataError
from vts_hw.files import WriteFailed, ensure_dir, filled_folder, write_atomic, write_json_atomic


def test_write_atomic_replaces_whole(tmp_path):
    p = tmp_path / "a.json"
    write_json_atomic(p, {"a": 1})
    write_json_atomic(p, {"a": 2})
    assert p.read_text().strip().replace(" ", "").replace("\n", "") == '{"a":2}'
    assert [x.name for x in tmp_path.iterdir()] == ["a.json"]


def test_disk_full_keeps_the_previous_file_and_leaves_no_tmp(small_disk):
    disk = small_disk(64)
    p = disk.path / "cal.json"
    write_atomic(p, b"old contents\n")
    disk.fill(leave=0)
    with pytest.raises(WriteFailed) as err:
        write_atomic(p, b"x" * 200_000)
    assert isinstance(err.value, DataError) and err.value.exit_code == 3
    msg = str(err.value)
    assert str(p) in msg and "no space left on device" in msg and "previous version is unchanged" in msg
    assert p.read_bytes() == b"old contents\n"
    assert disk.files() == {"cal.json": 13}  # no .tmp, no 0-byte file


def test_disk_full_new_file_leaves_nothing(small_disk):
    disk = small_disk(64)
    disk.fill(leave=0)
    with pytest.raises(WriteFailed, match="nothing was written there"):
        write_atomic(disk.path / "new.jpg", b"\xff\xd8" + b"\0" * 100_000)
    assert disk.files() == {}


def test_read_only_folder(readonly_dir):
    with pytest.raises(WriteFailed, match="read-only file system"):
        write_atomic(readonly_dir / "x.txt", "x")
    with pytest.raises(WriteFailed, match="read-only file system"):
        ensure_dir(readonly_dir / "sub", "simulated rig folder")


def test_ensure_dir_file_in_the_way(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(WriteFailed, match="a file of that name is in the way"):
        ensure_dir(tmp_path / "f")


def test_a_folder_made_for_a_write_that_failed_is_not_left_empty(tmp_path):
    """Found by the sweep's console full disk class: the daily QA's artifacts folder made for a
    run on a full disk was left empty (`unsaved-T-cam1/`), a folder that looks like a result."""
    made = tmp_path / "artifacts" / "unsaved-1-cam1"  # (its parent made for it too)
    with pytest.raises(WriteFailed):
        with filled_folder(made, "artifacts folder"):
            raise WriteFailed(made / "cam1-led-on.jpg", "no space left on device")
    assert not (tmp_path / "artifacts").exists()
    there = tmp_path / "run000001"  # a folder that was there stays, and so does what was written
    there.mkdir()
    with pytest.raises(OSError):
        with filled_folder(there):
            raise OSError(28, "No space left on device")
    assert there.is_dir()
    part = tmp_path / "unsaved-2-cam2"
    with pytest.raises(WriteFailed):
        with filled_folder(part) as d:
            write_atomic(d / "cam2-led-on.jpg", b"\xff\xd8")
            raise WriteFailed(d / "cam2-drift.png", "no space left on device")
    assert (part / "cam2-led-on.jpg").read_bytes() == b"\xff\xd8"
