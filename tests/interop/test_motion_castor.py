"""CASToR's files as CASToR 3.1.1 reads them (docs/decisions/0043), checked by a reader written
here from CASToR's sources, not from our writer:

* time: ``gOptions::ReadDataASCIIFile`` drops ``#`` comments, finds the keyword, splits at commas,
  and ``ConvertFromString`` parses each trigger with ``strtol`` (``20.3`` -> 20); times 1000;
  ``oDynamicDataManager::DynamicSwitch`` moves an event (ms) to the last trigger it has passed;
  ``vDeformation::PerformDeformation`` then undoes the data gathered so far with line ``new - 1``;
* frame: ``iDeformationRigid`` builds ``Translation(-t) Rx Ry Rz`` and pulls; a voxel sits at
  ``(i + 0.5 - N/2) * s`` along each matrix axis.

Two moves 0.4 s apart (constructed states) and a known point and rotation carried from a DICOM NM,
an Interfile and a CASToR-written Interfile mapping volume into CASToR's parameters."""

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vts_hw.motion.castor import plan_castor, write_castor
from vts_hw.motion.states import MotionState
from vts_hw.vision.registration import kabsch


# --------------------------------------------------------------------- CASToR's reading, from its sources
def _strtol(text: str) -> int:
    m = re.match(r"\s*([+-]?\d+)", text)
    if m is None:
        raise ValueError(f"CASToR: cannot convert {text!r} into uint32")
    return int(m.group(1))


def castor_reads(dyn, rig):
    """(trigger ms, forward matrices) as CASToR 3.1.1 takes them from the two files."""

    def keyword_line(lines, key):
        for i, raw in enumerate(lines):
            line = raw.split("#", 1)[0]
            if key in line:
                return i, line.split(":", 1)[1].strip()
        raise KeyError(key)

    d = dyn.read_text().splitlines()
    n = _strtol(keyword_line(d, "nb_motion_triggers")[1])
    _, rest = keyword_line(d, "timestamp_motion_triggers")
    ms = [_strtol(x) * 1000 for x in (rest.split(",") if n > 1 else [rest])][:n]
    r = rig.read_text().splitlines()
    i, _ = keyword_line(r, "Transformation_parameters")
    mats = [source_matrix([float(x) for x in r[i + 1 + k].split(",")]) for k in range(n)]  # raw lines
    return ms, mats


def source_matrix(p):
    tx, ty, tz = p[:3]
    a, b, c = np.radians(p[3:6])
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = rx @ ry @ rz
    m[:3, 3] = [-tx, -ty, -tz]
    return m


def castor_lines_of_events(trigger_ms, event_ms):
    """Per event (ms, increasing): the line CASToR projects it with, and the line whose backward
    deformation later undoes it (DynamicSwitch, then PerformDeformation's ``index - 1``)."""
    current, used, undo, pending = 0, [], [], []
    for t in event_ms:
        new = current
        for mt in range(current, len(trigger_ms)):
            if t >= trigger_ms[mt] and mt > new:
                new = mt
        if new != current:
            undo += [new - 1] * len(pending)
            pending, current = [], new
        used.append(current)
        pending.append(t)
    undo += [current] * len(pending)  # the end of the frame: the current line
    return np.array(used), np.array(undo)


# --------------------------------------------------------------------- two moves 0.4 s apart
def _state(k, a, b, rotvec_deg=(0, 0, 0), shift=(0, 0, 0)):
    R = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    return MotionState(k, a, b, [], R, np.asarray(shift, float), 100, 0)


POSES = [((0, 0, 0), (0, 0, 0)), ((0, 0, 1.5), (4, -2, 1)), ((1, 0.5, 2.5), (9, -3, 6)), ((0, 2, 0), (-5, 1, 3))]
CENTRE = np.array([12.0, -30.0, 40.0])  # the mapping volume's centre, SPECT frame
VOLUME = {"file": "phantom.dcm", "format": "dicom", "centre_mm": CENTRE.tolist(), "patient_position": "HFS"}


@pytest.mark.parametrize(
    "starts, merged",
    [
        ((-3.0, 20.3, 20.7, 40.0), []),  # B holds most of second 20
        ((-3.0, 20.6, 21.0, 40.0), [1]),
    ],
)  # A holds it: B merged
def test_moves_04s_apart_are_whole_seconds_castor_honours(tmp_path, starts, merged):
    ends = list(starts[1:]) + [60.0]
    states = [_state(k, a, b, *POSES[k]) for k, (a, b) in enumerate(zip(starts, ends))]
    plan = plan_castor(states, 0.0, clock="spect", frame="spect", volume=VOLUME)
    assert plan.why is None
    dyn, rig = write_castor(plan.triggers, plan.params, tmp_path, comment="a comment CASToR drops")
    assert re.search(r"^timestamp_motion_triggers: 0(,\d+)*$", dyn.read_text(), re.M)
    ms, mats = castor_reads(dyn, rig)
    assert ms == [1000 * n for n in plan.triggers]
    assert [s for s in range(4) if s not in plan.states] == merged
    assert len(plan.merged) == len(merged) and all("state 1 (20." in m for m in plan.merged)
    events = np.arange(0, 60000, 5)  # a list-mode event every 5 ms
    used, undo = castor_lines_of_events(ms, events)
    assert np.array_equal(used, undo)  # no state skipped, none undone wrongly
    # each event's line is the state holding most of its whole second
    t = events / 1000.0
    true_state = np.searchsorted(np.asarray(starts), t, side="right") - 1
    majority = np.array(
        [max(range(4), key=lambda k: (min(n + 1, ends[k]) - max(n, starts[k] if k else -9), -k)) for n in range(60)]
    )
    assert np.array_equal(np.asarray(plan.states)[used], majority[t.astype(int)])
    wrong_s = 0.005 * np.sum(np.asarray(plan.states)[used] != true_state)
    assert wrong_s <= 0.5 * 2 + 1e-9  # two boundaries, at most 0.5 s each
    # each line's transform takes its state's positions back to the pose at the acquisition start
    flip = np.diag([1.0, 1.0, -1.0])
    x0 = np.array([[0.0, 0.0, 0.0], [80.0, -40.0, 120.0], [-100.0, 60.0, -30.0]])
    R0, T0 = states[0].R, states[0].T
    for line, k in enumerate(plan.states):
        s = states[k]
        x_k = (x0 - T0) @ R0 @ s.R.T + s.T
        back = ((x_k - CENTRE) @ flip) @ mats[line][:3, :3].T + mats[line][:3, 3]
        assert np.abs(back - (x0 - CENTRE) @ flip).max() < 1e-3
    assert np.allclose(mats[0], np.eye(4))  # line 1: the identity


def test_fractional_triggers_are_what_castor_would_misread(tmp_path):
    """What the export wrote before: CASToR reads 20.3 and 20.7 as 20 and 20, skips line 2, and
    undoes the first state's data with line 2's transform."""
    dyn = tmp_path / "old.dyn"
    dyn.write_text("nb_motion_triggers: 3\ntimestamp_motion_triggers: 0,20.3,20.7\n")
    rig = tmp_path / "old_rigid.txt"
    rig.write_text("Transformation_mode: 0\nTransformation_parameters:\n0,0,0,0,0,0\n1,0,0,0,0,0\n2,0,0,0,0,0\n")
    ms, _ = castor_reads(dyn, rig)
    assert ms == [0, 20000, 20000]
    used, undo = castor_lines_of_events(ms, np.arange(0, 30000, 5))
    assert 1 not in used and np.any(undo != used)


def test_no_castor_file_without_the_spect_clock_a_mapping_or_its_volume():
    states = [_state(0, 0, 10), _state(1, 10, 20, *POSES[1])]
    host = plan_castor(states, 0.0, clock="host", frame="spect", volume=VOLUME).why
    assert host.startswith("CASToR files not written") and "host-clock" in host and "list-mode" in host
    assert "VTS frame" in plan_castor(states, 0.0, clock="spect", frame="vts", volume=VOLUME).why
    assert "vts calibrate spect" in plan_castor(states, 0.0, clock="spect", frame="spect", volume=None).why
    ffs = plan_castor(states, 0.0, clock="spect", frame="spect", volume={**VOLUME, "patient_position": "FFS"}).why
    assert "FFS" in ffs and "HFS" in ffs
    states[1].R = None
    assert "no pose" in plan_castor(states, 0.0, clock="spect", frame="spect", volume=VOLUME).why


# --------------------------------------------------------------------- the frame, from three kinds of volume
VOX = 4.0
SHAPE = (48, 44, 40)  # file order: slices/frames, rows, columns
BLOBS = np.array(
    [
        (10.3, 12.2, 14.1),
        (10.0, 30.4, 20.0),
        (24.2, 14.0, 30.3),
        (26.0, 33.7, 12.2),
        (36.1, 20.0, 24.4),
        (38.4, 34.2, 31.0),
        (20.0, 24.3, 25.9),
    ]
)  # (slice, row, column)


def _blobs():
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in SHAPE], indexing="ij"), -1).astype(float)
    data = np.ones(SHAPE)
    for b in BLOBS:
        data += 1000.0 * np.exp(-np.sum((idx - b) ** 2, axis=-1) / (2 * 1.5**2))
    return data.astype(np.float32)


def _from_centre(idx):
    """(column, row, slice) mm from the matrix centre, for (slice, row, column) indices."""
    idx = np.atleast_2d(idx)
    return (idx[:, ::-1] - (np.array(SHAPE[::-1]) - 1) / 2) * VOX


def _interfile(path, extra):
    data = _blobs()
    path.with_suffix(".img").write_bytes(data.astype("<f4").tobytes())
    lines = [
        "!INTERFILE :=",
        "!imaging modality := nucmed",
        "!version of keys := 3.3",
        *extra[:1],
        f"!name of data file := {path.with_suffix('.img').name}",
        "imagedata byte order := LITTLEENDIAN",
        "number of dimensions := 3",
        f"!matrix size [1] := {SHAPE[2]}",
        f"!matrix size [2] := {SHAPE[1]}",
        f"!matrix size [3] := {SHAPE[0]}",
        "!number format := short float",
        "!number of bytes per pixel := 4",
        *[f"scaling factor (mm/pixel) [{i}] := {VOX}" for i in (1, 2, 3)],
        *extra[1:],
        "!END OF INTERFILE :=",
    ]
    path.write_text("\n".join(lines) + "\n")


def castor_written(tmp_path):
    """A CASToR-written image: [1], [2], [3] are CASToR's x, y, z (x patient left, y anterior, z head
    for a head-first supine patient, CASToR's documented frame); it writes its FOV offset (0) under
    'first pixel offset'. Truth in CASToR coordinates straight from its voxel rule."""
    path = tmp_path / "castor_recon.hdr"
    _interfile(path, ["CASToR version := 3.1.1", *[f"first pixel offset (mm) [{i}] := 0" for i in (1, 2, 3)]])
    to_castor = lambda idx: _from_centre(idx)  # noqa: E731
    to_lps = lambda idx: _from_centre(idx) * [1, -1, 1] + [5, 7, -300]  # noqa: E731 x L, y A, z S
    return path, to_castor, to_lps


def display_interfile(tmp_path):
    """An Interfile laid out as displayed: [1] the patient's right to left, [2] anterior to posterior,
    [3] head to feet; its first pixel offset puts the matrix centre at SPECT (15, -25, 40)."""
    path = tmp_path / "recon.h33"
    first = np.array([15.0, -25.0, 40.0]) + (np.array(SHAPE[::-1]) - 1) / 2 * VOX * [-1, 1, -1]
    _interfile(path, ["", *[f"first pixel offset (mm) [{i}] := {first[i - 1]}" for i in (1, 2, 3)]])
    lps = lambda idx: _from_centre(idx) * [1, 1, -1] + [-40, 60, 900]  # noqa: E731 L, P, S
    to_castor = lambda idx: _from_centre(idx) * [1, -1, -1]  # noqa: E731 L, A, S
    return path, to_castor, lps


def dicom_nm(tmp_path):
    """A DICOM NM volume in coronal slices (rows run to the feet, frames posterior), its
    patient-coordinate origin far from the volume; truth from DICOM's own IPP/IOP rule, and
    CASToR's frame for a head-first supine patient (x L, y A, z S) from the volume's centre."""
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.sequence import Sequence
    from pydicom.uid import ExplicitVRLittleEndian, generate_uid

    row_cos, col_cos = np.array([1.0, 0, 0]), np.array([0, 0, -1.0])
    normal = np.cross(row_cos, col_cos)
    ipp = np.array([-60.0, -150.0, 1100.0])
    data = _blobs()
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.20"
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID, ds.SOPInstanceUID, ds.Modality = meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID, "NM"
    ds.PatientPosition = "HFS"
    ds.NumberOfFrames, ds.Rows, ds.Columns = SHAPE
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
    ds.PixelSpacing, ds.SpacingBetweenSlices = [str(VOX), str(VOX)], str(VOX)
    det = Dataset()
    det.ImagePositionPatient = [str(v) for v in ipp]
    det.ImageOrientationPatient = [str(v) for v in (*row_cos, *col_cos)]
    ds.DetectorInformationSequence = Sequence([det])
    ds.PixelData = np.rint(data).astype("<u2").tobytes()
    path = tmp_path / "recon.dcm"
    ds.save_as(path, enforce_file_format=True)

    def to_lps(idx):
        idx = np.atleast_2d(idx)
        return ipp + idx[:, 2:3] * VOX * row_cos + idx[:, 1:2] * VOX * col_cos + idx[:, 0:1] * VOX * normal

    centre = to_lps((np.array(SHAPE) - 1) / 2)
    to_castor = lambda idx: (to_lps(idx) - centre) * [1, -1, 1]  # noqa: E731
    return path, to_castor, to_lps


@pytest.mark.parametrize("make", [dicom_nm, display_interfile, castor_written])
def test_a_known_point_and_rotation_reach_castor_parameters(tmp_path, make):
    """The VTS sees the phantom and the patient (any rigid placement of the room); the mapping is
    made from the volume; the patient turns 4 deg about CASToR's z (the scanner's axis) and 2 deg
    about its x, and shifts (10, 4, 6) mm along CASToR's x, y, z. CASToR's line for that state
    must hold angles (-2, 0, -4) deg and take the known point, moved, back to where it was."""
    from vts_hw.procedures.spect_mapping import SpectMapping

    path, to_castor, to_phys = make(tmp_path)
    # from CASToR coordinates to the right-handed room the VTS sees (through the volume's truth)
    c_sph, p_sph = to_castor(BLOBS), to_phys(BLOBS)
    fit = kabsch(c_sph * [1, -1, 1], p_sph)  # CASToR is left-handed: through a mirror
    to_room = lambda y: fit.apply(np.atleast_2d(y) * [1, -1, 1])  # noqa: E731
    assert np.abs(to_room(c_sph) - p_sph).max() < 1e-6  # the truths agree with each other
    G = Rotation.from_rotvec([0.2, -0.4, 0.1]).as_matrix()
    to_vts = lambda x: x @ G.T + [150.0, -80.0, 2500.0]  # noqa: E731

    mapping = SpectMapping.from_volume(to_vts(p_sph), path).analyze()
    vol = mapping.spect_volume
    assert mapping.fre_mm < 0.05 and vol["file"] == path.name
    assert (vol["format"], vol["patient_position"], vol["castor_image"]) == {
        dicom_nm: ("dicom", "HFS", False),
        display_interfile: ("interfile", None, False),
        castor_written: ("interfile", None, True),
    }[make]

    th, ph = np.radians(4.0), np.radians(2.0)
    Rz = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(ph), -np.sin(ph)], [0, np.sin(ph), np.cos(ph)]])
    R_c, T_c = Rz @ Rx, np.array([10.0, 4.0, 6.0])
    markers = np.array([[0, 0, 0], [90, 20, -60], [-70, 50, 40], [30, -80, 110], [-20, 60, -120], [110, 5, 15.0]])
    moved = markers @ R_c.T + T_c
    spect = [mapping.transform.apply(to_vts(to_room(m))) for m in (markers, moved)]
    pose = kabsch(spect[0], spect[1])
    states = [MotionState(0, -2.0, 30.0, [], np.eye(3), np.zeros(3)), MotionState(1, 30.0, 60.0, [], pose.R, pose.t)]
    plan = plan_castor(states, 0.0, clock="spect", frame="spect", volume=mapping.spect_volume)
    assert plan.why is None and plan.triggers == [0, 30]
    params = plan.params[1]
    assert np.allclose(params[3:], [-2.0, 0.0, -4.0], atol=0.01)
    p = np.array([50.0, 30.0, 20.0])  # 50 mm left, 30 anterior, 20 towards the head (CASToR)
    M = source_matrix(params)
    assert np.abs(M[:3, :3] @ (R_c @ p + T_c) + M[:3, 3] - p).max() < 0.02
