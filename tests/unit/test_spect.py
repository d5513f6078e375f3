"""The SPECT side: volumes, the three readers, sphere centroids against the simulator's truth."""

from __future__ import annotations

import shutil

import numpy as np
import pydicom  # a dependency of vts-hw: never skipped
import pytest

from vts_hw.errors import DataError
from vts_hw.sim_devices.spect import SimSpect, phantom_centres, write_volume
from vts_hw.spect import Volume, VolumeReader, find_spheres, read_volume, reader_for, register_reader
from vts_hw.spect.readers import list_readers
from vts_hw.spect.volume import CANONICAL_DIRECTION

EXTENSIONS = [".h33", ".hdr", ".dcm", ".npz"]
OFFGRID = (1.37, -0.81, 2.06)  # mm: the phantom is not aligned with the voxel grid


def rms(err) -> float:
    return float(np.sqrt((np.asarray(err) ** 2).sum(-1).mean()))


# --- Volume ---------------------------------------------------------------------------------


def test_index_to_mm_canonical_layout():
    v = Volume(np.zeros((4, 5, 6)), (3.0, 4.0, 5.0), (10.0, 20.0, 30.0))
    assert np.allclose(v.index_to_mm((0, 0, 0)), (10, 20, 30))
    assert np.allclose(v.index_to_mm((1, 2, 3)), (10 + 3 * 5, 20 + 2 * 4, 30 + 1 * 3))
    pts = np.random.default_rng(0).uniform(0, 4, (10, 3))
    assert np.allclose(v.mm_to_index(v.index_to_mm(pts)), pts)


def test_canonical_keeps_every_voxel_in_place():
    rng = np.random.default_rng(1)
    data = rng.normal(size=(4, 5, 6))
    direction = np.array([[-1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # axes: -X, +Z, -Y
    v = Volume(data, (2.0, 3.0, 4.0), (1.0, 2.0, 3.0), direction)
    c = v.canonical()
    assert np.allclose(c.direction, CANONICAL_DIRECTION)
    assert c.data.shape == (5, 6, 4) and c.voxel_size == (3.0, 4.0, 2.0)
    for idx in [(0, 0, 0), (3, 4, 5), (1, 2, 3)]:
        where = c.mm_to_index(v.index_to_mm(idx))
        assert np.allclose(where, np.round(where))
        assert c.data[tuple(np.round(where).astype(int))] == data[idx]


@pytest.mark.parametrize("ext", EXTENSIONS)
def test_round_trip_keeps_data_and_geometry(tmp_path, ext):
    """An anisotropic, asymmetric volume comes back voxel for voxel, in the same place."""
    rng = np.random.default_rng(2)
    data = rng.integers(0, 3000, size=(5, 6, 7)).astype(np.float32)
    v = Volume(data, (3.0, 4.0, 5.0), (-11.0, 22.5, -33.25))
    back = read_volume(write_volume(v, tmp_path / f"v{ext}"))
    assert back.data.shape == data.shape
    assert np.allclose(back.voxel_size, v.voxel_size)
    assert np.allclose(back.origin, v.origin, atol=1e-4)
    assert np.allclose(back.direction, CANONICAL_DIRECTION)
    assert np.array_equal(back.data, data)


@pytest.mark.parametrize("ext", EXTENSIONS)
def test_non_canonical_volume_is_written_in_place(tmp_path, ext):
    data = np.random.default_rng(3).integers(0, 100, size=(3, 4, 5)).astype(np.float32)
    v = Volume(data, (2.0, 3.0, 4.0), (5.0, 6.0, 7.0), np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, -1]]))
    back = read_volume(write_volume(v, tmp_path / f"v{ext}"))
    for idx in [(0, 0, 0), (2, 3, 4), (1, 0, 3)]:
        where = np.round(back.mm_to_index(v.index_to_mm(idx))).astype(int)
        assert back.data[tuple(where)] == data[idx]


def test_dicom_is_standard_transaxial(tmp_path):
    v = Volume(np.ones((3, 4, 5), np.float32), (4.4, 4.4, 4.4), (0.0, 0.0, 0.0))
    ds = pydicom.dcmread(write_volume(v, tmp_path / "v.dcm"))
    assert ds.Modality == "NM" and ds.NumberOfFrames == 3
    assert [float(x) for x in ds.DetectorInformationSequence[0].ImageOrientationPatient] == [1, 0, 0, 0, 1, 0]
    assert float(ds.SpacingBetweenSlices) == pytest.approx(4.4)


# --- sphere centroids against the truth -----------------------------------------------------


@pytest.mark.parametrize("ext", EXTENSIONS)
def test_seven_spheres_found_at_the_truth(tmp_path, ext):
    truth = phantom_centres(translation=OFFGRID)
    assert np.ptp(truth, axis=0).max() > 130  # the ~15 cm phantom
    sim = SimSpect(seed=11)
    path = sim.write(tmp_path / f"phantom{ext}", truth)
    if ext == ".npz":  # the truth stays out of the file
        assert sorted(np.load(path).files) == ["data", "origin", "voxel_size"]
    vol = read_volume(path)
    assert vol.voxel_size == pytest.approx((4.4, 4.4, 4.4))
    result = find_spheres(vol, 7, reference=truth)
    assert result.ok, result.problem
    assert result.centroids.shape == (7, 3)
    err = rms(result.centroids - truth)
    print(
        f"{ext}: centroid RMS error vs truth {err:.3f} mm "
        f"(max {np.linalg.norm(result.centroids - truth, axis=1).max():.3f} mm)"
    )
    assert err < 0.5  # measured ≈ 0.05 mm; 0.5 mm = 0.11 voxel


def test_translation_moves_the_centroids_by_the_translation(tmp_path):
    base = phantom_centres(translation=OFFGRID)
    shift = np.array([3.3, 10.0, -7.1])
    a = find_spheres(read_volume(SimSpect(seed=1).write(tmp_path / "a.npz", base)), 7, reference=base)
    b = find_spheres(read_volume(SimSpect(seed=2).write(tmp_path / "b.dcm", base + shift)), 7, reference=base + shift)
    moved = b.centroids - a.centroids
    print(f"translation error RMS {rms(moved - shift):.3f} mm")
    assert rms(moved - shift) < 0.3


def test_rotated_phantom_ordered_by_reference():
    truth = phantom_centres(translation=(5.0, -3.0, 8.0), rvec=(0.1, 0.5, -0.2))
    result = find_spheres(SimSpect(seed=4).volume(truth), 7, reference=truth)
    assert result.ok
    assert rms(result.centroids - truth) < 0.5
    plain = find_spheres(SimSpect(seed=4).volume(truth), 7)
    assert np.all(np.diff(plain.centroids[:, 2]) >= 0)  # default order: ascending Z


def test_fewer_spheres_are_reported_and_strict_raises(tmp_path):
    truth = phantom_centres()[:6]
    path = SimSpect(seed=5).write(tmp_path / "six.npz", truth)
    vol = read_volume(path)
    result = find_spheres(vol, 7)
    assert not result.ok and "found 6 spheres, expected 7" in result.problem
    assert len(result.centroids) == 6
    with pytest.raises(DataError, match="six.npz"):
        find_spheres(vol, 7, strict=True)


def test_extra_blob_is_reported_and_the_hottest_kept():
    truth = phantom_centres()
    stray = np.array([[100.0, -100.0, 100.0]])
    sim = SimSpect(seed=6, activity_spread=0.0)
    hot = sim.expected(truth)
    weak = SimSpect(seed=6, counts_per_sphere=1.5e4, background=0.0).expected(stray)
    vol = Volume(np.random.default_rng(6).poisson(hot.data + weak.data).astype(np.float32), hot.voxel_size, hot.origin)
    result = find_spheres(vol, 7, reference=truth)
    assert result.n_blobs == 8 and "found 8 blobs" in result.problem
    assert rms(result.centroids - truth) < 0.5


# --- bad files --------------------------------------------------------------------------------


def _one_line_error(path, call=read_volume):
    with pytest.raises(DataError) as info:
        call(path)
    msg = str(info.value)
    assert str(path) in msg and "\n" not in msg
    return msg


@pytest.fixture()
def interfile(tmp_path):
    v = Volume(np.arange(60, dtype=np.float32).reshape(3, 4, 5), (4.4,) * 3, (0.0, 0.0, 0.0))
    return write_volume(v, tmp_path / "v.h33")


@pytest.mark.parametrize(
    "key",
    [
        "!matrix size [3]",
        "!number format",
        "!name of data file",
        "scaling factor (mm/pixel) [1]",
        "!number of bytes per pixel",
    ],
)
def test_interfile_missing_key(interfile, key):
    lines = [ln for ln in interfile.read_text().splitlines() if not ln.startswith(key)]
    interfile.write_text("\n".join(lines))
    assert f"missing key '{key}'" in _one_line_error(interfile)


def test_interfile_size_mismatch(interfile):
    data = interfile.with_suffix(".img")
    data.write_bytes(data.read_bytes()[:-2])
    assert "the header says" in _one_line_error(interfile)


def test_interfile_unknown_number_format(interfile):
    interfile.write_text(interfile.read_text().replace("unsigned integer", "complex"))
    assert "unknown number format 'complex'" in _one_line_error(interfile)


def test_interfile_bad_number_and_missing_data_file(interfile):
    text = interfile.read_text()
    interfile.write_text(text.replace("!matrix size [1] := 5", "!matrix size [1] := five"))
    assert "not a number" in _one_line_error(interfile)
    interfile.write_text(text)
    interfile.with_suffix(".img").unlink()
    assert "cannot read the data file" in _one_line_error(interfile)


@pytest.mark.parametrize(
    "change, expected",
    [
        (
            ("!name of data file := v.img", "!name of data file := v\x00.img"),
            "key '!name of data file' holds a NUL byte",
        ),
        (
            ("!name of data file := v.img", "!name of data file := /dev/zero"),
            "the data file /dev/zero is not a regular file",
        ),
        (("!name of data file := v.img", "!name of data file := ."), "is not a regular file"),
        (
            ("!name of data file := v.img", "!name of data file := " + "v" * 300 + ".img"),
            "cannot read the data file 'vvvvvvvvvvvvvvvvvvvvvvvvvvvvvvvvvvvvvvvv'... (304 characters) "
            "(File name too long)",
        ),
        (
            ("scaling factor (mm/pixel) [1] := 4.4", "scaling factor (mm/pixel) [1] := 0"),
            "key 'scaling factor (mm/pixel) [1]' is 0.0, not a positive number of mm",
        ),
        (
            ("scaling factor (mm/pixel) [2] := 4.4", "scaling factor (mm/pixel) [2] := nan"),
            "key 'scaling factor (mm/pixel) [2]' is nan",
        ),
        (
            ("!data offset in bytes := 0", "!data offset in bytes := -8"),
            "key '!data offset in bytes' is -8, not a byte count",
        ),
        (("first pixel offset (mm) [3] := ", "first pixel offset (mm) [3] := inf ;"), "'first pixel offset (mm)' is"),
    ],
)
def test_interfile_values_the_reader_cannot_use(interfile, change, expected):
    """Header values found by bench/fuzz.py that used to end in a traceback."""
    text = interfile.read_text()
    assert change[0] in text
    interfile.write_text(text.replace(*change))
    assert expected in _one_line_error(interfile)


def test_not_an_interfile_header(tmp_path):
    p = tmp_path / "x.hdr"
    p.write_text("hello\n")
    assert "not an Interfile header" in _one_line_error(p)


def test_not_dicom(tmp_path):
    p = tmp_path / "x.dcm"
    p.write_bytes(b"\0" * 300)
    assert "not a DICOM file" in _one_line_error(p)


@pytest.fixture()
def dicom(tmp_path):
    v = Volume(np.ones((3, 4, 5), np.float32), (4.4,) * 3, (0.0, 0.0, 0.0))
    return write_volume(v, tmp_path / "v.dcm")


def test_dicom_not_nm(dicom):
    ds = pydicom.dcmread(dicom)
    ds.Modality = "CT"
    ds.save_as(dicom)
    assert "not a DICOM NM image (Modality is CT)" in _one_line_error(dicom)


@pytest.mark.parametrize("key", ["PixelSpacing", "DetectorInformationSequence", "SpacingBetweenSlices"])
def test_dicom_missing_geometry(dicom, key):
    ds = pydicom.dcmread(dicom)
    delattr(ds, key)
    if key == "SpacingBetweenSlices":
        del ds.SliceThickness
    ds.save_as(dicom)
    assert "DICOM NM without" in _one_line_error(dicom)


def test_dicom_frames_not_matching(dicom):
    ds = pydicom.dcmread(dicom)
    ds.NumberOfFrames = 4
    ds.save_as(dicom)
    _one_line_error(dicom)


@pytest.mark.parametrize(
    "old, new, expected",
    [
        # an element with an unknown value representation: pydicom's NotImplementedError
        (
            b"\x28\x00\x30\x00DS",
            b"\x28\x00\x30\x00D2",
            "a corrupt DICOM data element after element (0028,0011) (NotImplementedError: Unknown Value "
            "Representation '0x44 0x32' in tag (0028,0030))",
        ),
        # a decimal string that is not a number
        (b"4.4\\4.4", b"4.4\\4'4", "DICOM PixelSpacing is ['4.4', \"4'4\"], not 2 finite numbers"),
        # the Detector Information Sequence's VR garbled into bytes (its item then is an int)
        (b"\x54\x00\x22\x00SQ", b"\x54\x00\x22\x00OB", "DICOM NM without ImagePositionPatient/ImageOrientationPatient"),
    ],
)
def test_dicom_corrupt_elements(dicom, old, new, expected):
    """Corrupt elements found by bench/fuzz.py: pydicom decodes lazily, so they used to raise
    pydicom's or float()'s own exceptions from deep in the reader."""
    raw = dicom.read_bytes()
    assert raw.count(old) == 1
    dicom.write_bytes(raw.replace(old, new))
    assert expected in _one_line_error(dicom)


@pytest.mark.parametrize("drop", ["voxel_size", "origin", "data"])
def test_npz_missing_key(tmp_path, drop):
    p = tmp_path / "v.npz"
    arrays = {"data": np.zeros((2, 2, 2)), "voxel_size": np.ones(3), "origin": np.zeros(3)}
    del arrays[drop]
    np.savez(p, **arrays)
    assert f"npz missing key '{drop}'" in _one_line_error(p)


def test_npz_bad_content(tmp_path):
    p = tmp_path / "v.npz"
    np.savez(p, data=np.zeros((2, 2)), voxel_size=np.ones(3), origin=np.zeros(3))
    assert "must be 3-D" in _one_line_error(p)
    np.savez(p, data=np.zeros((2, 2, 2)), voxel_size=np.ones(2), origin=np.zeros(3))
    assert "'voxel_size' must be 3 numbers" in _one_line_error(p)
    p.write_bytes(b"not a zip")
    assert "not a readable .npz" in _one_line_error(p)


def _npz_bytes(tmp_path) -> bytearray:
    p = tmp_path / "good.npz"
    np.savez_compressed(p, data=np.arange(64.0).reshape(4, 4, 4), voxel_size=np.ones(3), origin=np.zeros(3))
    return bytearray(p.read_bytes())


def test_npz_broken_archives(tmp_path):
    """Archives zipfile and zlib refuse with their own exceptions (found by bench/fuzz.py)."""
    p = tmp_path / "v.npz"
    raw = _npz_bytes(tmp_path)
    c = raw.find(b"PK\x01\x02")  # the first central directory record
    version = raw.copy()
    version[c + 6] = 160  # "version needed to extract" 16.0: zipfile's NotImplementedError
    p.write_bytes(version)
    assert "not a readable .npz archive (NotImplementedError: zip file version 16.0)" in _one_line_error(p)
    patched = raw.copy()
    patched[c + 8] |= 0x20  # flag bit 5, compressed patched data
    p.write_bytes(patched)
    assert "compressed patched data" in _one_line_error(p)
    deflate = raw.copy()
    start = 30 + int.from_bytes(raw[26:28], "little") + int.from_bytes(raw[28:30], "little")
    deflate[start : start + 8] = b"\xff" * 8  # the first member's compressed data garbled
    p.write_bytes(deflate)
    assert "not a readable .npz archive (error: Error -3 while decompressing" in _one_line_error(p)


def test_npz_header_claiming_more_than_the_member_holds(tmp_path):
    import io
    import zipfile

    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "<f8", "fortran_order": False, "shape": (4000, 4000, 4000)})
    p = tmp_path / "v.npz"
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("data.npy", head.getvalue() + b"\0" * 64)  # 512 GB claimed, 64 bytes held
    assert "'data' claims 512000000000 bytes of float64 (4000, 4000, 4000)" in _one_line_error(p)


def test_missing_file_and_unknown_format(tmp_path):
    assert "no such file" in _one_line_error(tmp_path / "nothing.npz")
    p = tmp_path / "mystery.bin"
    p.write_bytes(b"\x01\x02" * 400)
    assert "not a volume file of a known format" in _one_line_error(p)


# --- the registry -----------------------------------------------------------------------------


def test_registry_by_extension_then_content(tmp_path):
    v = Volume(np.arange(24, dtype=np.float32).reshape(2, 3, 4), (4.4,) * 3, (0.0, 0.0, 0.0))
    for ext, name in [(".h33", "interfile"), (".hdr", "interfile"), (".dcm", "dicom"), (".npz", "npz")]:
        path = write_volume(v, tmp_path / f"a{ext}")
        assert reader_for(path).name == name
        renamed = tmp_path / f"renamed_{ext[1:]}.dat"  # no telling extension: content decides
        shutil.copy(path, renamed)
        assert reader_for(renamed).name == name
        assert np.array_equal(read_volume(renamed).data, v.data)
    # a format override
    shutil.copy(tmp_path / "a.npz", tmp_path / "weird.h33")
    assert np.array_equal(read_volume(tmp_path / "weird.h33", fmt="npz").data, v.data)


def test_a_vendor_reader_can_be_added(tmp_path):
    before = list_readers()
    p = tmp_path / "scan.vnd"
    p.write_bytes(b"VENDOR")
    vol = Volume(np.zeros((2, 2, 2)), (1.0, 1.0, 1.0), (0.0, 0.0, 0.0))
    try:
        register_reader(VolumeReader("vendor", (".vnd",), lambda h: h.startswith(b"VENDOR"), lambda path: vol))
        assert read_volume(p) is vol
    finally:
        from vts_hw.spect import readers as mod

        mod._REGISTRY.unregister("vendor")
    assert list_readers() == before


def test_dicom_float_data_is_rescaled(tmp_path):
    data = np.random.default_rng(7).uniform(-5.0, 900.0, size=(3, 4, 5)).astype(np.float32)
    v = Volume(data, (4.4,) * 3, (0.0, 0.0, 0.0))
    back = read_volume(write_volume(v, tmp_path / "f.dcm"))
    assert np.abs(back.data - data).max() <= (905.0 / 65535) * 0.51 + 1e-4


def test_interfile_big_endian_float(interfile):
    header = interfile.read_text()
    data = np.fromfile(interfile.with_suffix(".img"), "<u2").astype(">f4")
    interfile.with_suffix(".img").write_bytes(data.tobytes())
    interfile.write_text(
        header.replace("LITTLEENDIAN", "BIGENDIAN")
        .replace("unsigned integer", "float")
        .replace("bytes per pixel := 2", "bytes per pixel := 4")
    )
    back = read_volume(interfile)
    assert np.array_equal(back.data, np.arange(60, dtype=np.float32).reshape(3, 4, 5))
