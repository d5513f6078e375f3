"""The motion exports read back: the 6-DOF series (CSV and JSON), the respiratory trace, the
list-mode subsets, and CASToR's two files through a reader written here from CASToR's rules
(not from the writer): ``#`` comments dropped, keyword lines, comma-separated numbers, the first
trigger 0. On the host clock no CASToR file is written (CASToR reads list-mode seconds)."""

import csv
import json
import os
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from motion_truth import patient_tracks
from vts_hw.motion import analyze_motion, marker_series
from vts_hw.motion.castor import write_castor
from vts_hw.motion.exports import export_motion
from vts_hw.sim_devices.sync_truth import SCENE_VOLUME


def read_castor_keyword(path, key):
    """The values after ``key:`` in a CASToR ASCII file (one line, or the lines that follow
    when nothing follows the colon), as float rows."""
    lines = [ln.split("#", 1)[0] for ln in path.read_text(encoding="ascii").splitlines()]
    for i, line in enumerate(lines):
        if line.split(":", 1)[0].strip().lower() == key.lower():
            rest = line.split(":", 1)[1].strip()
            if rest:
                return [[float(x) for x in re.split(r"[,\s]+", rest) if x]]
            rows = []
            for nxt in lines[i + 1 :]:
                if not nxt.strip() or ":" in nxt:
                    break
                rows.append([float(x) for x in re.split(r"[,\s]+", nxt.strip()) if x])
            return rows
    raise KeyError(key)


LEAD = 2.5  # the SPECT started 2.5 s before the first frame


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """On the host clock (no list-mode)."""
    patient, tracks, _, t0 = patient_tracks(seed=5, duration_s=60.0, n_moves=2)
    r = analyze_motion(marker_series(tracks))
    out = tmp_path_factory.mktemp("export")
    (out / "castor_motion.dyn").write_text(
        "nb_motion_triggers: 1\ntimestamp_motion_triggers: 0\n"
    )  # an earlier export's
    (out / "yrtpet_lor_motion.csv").write_text("0,1,0,0,0,0,1,0,0,0,0,1,0,0\n")  # ... too
    paths = export_motion(r, out, n_bins=4, volume=SCENE_VOLUME)
    return patient, r, out, paths, t0


@pytest.fixture(scope="module")
def synced(tmp_path_factory):
    """The same patient with SPECT times (as the sync analysis makes them) and the scene's frame."""
    patient, tracks, _, t0 = patient_tracks(seed=5, duration_s=60.0, n_moves=2)
    r = analyze_motion(marker_series(tracks.with_spect(None, lambda h: np.asarray(h) - t0 + LEAD)))
    out = tmp_path_factory.mktemp("export_synced")
    paths = export_motion(r, out, n_bins=4, volume=SCENE_VOLUME)
    return patient, r, out, paths, t0


def test_no_castor_file_on_the_host_clock(exported):
    _, r, out, paths, _ = exported
    assert not (out / "castor_motion.dyn").exists() and not (out / "castor_motion_rigid.txt").exists()
    assert {p.name for p in paths} == {"motion_6dof.csv", "motion_6dof.json", "respiration.csv", "subsets.json"}
    assert len(paths.notes) == 2 and "CASToR files not written" in paths.notes[0] and "host" in paths.notes[0]
    assert paths.notes[0].endswith("(removed castor_motion.dyn, which an earlier export left there)")
    assert paths.notes[1].startswith("YRT-PET LOR motion file not written: the times are host-clock seconds")
    assert paths.notes[1].endswith("(removed yrtpet_lor_motion.csv, which an earlier export left there)")
    assert not (out / "yrtpet_lor_motion.csv").exists()
    doc = json.loads((out / "motion_6dof.json").read_text())
    assert doc["castor"] == {"written": False, "why": paths.notes[0]}
    assert doc["yrtpet"] == {"written": False, "why": paths.notes[1]}
    assert "host clock" in json.loads((out / "subsets.json").read_text())["clock"]


def test_castor_files_have_whole_second_triggers_one_line_each(synced):
    _, r, out, _, _ = synced
    dyn, rig = out / "castor_motion.dyn", out / "castor_motion_rigid.txt"
    n = int(read_castor_keyword(dyn, "nb_motion_triggers")[0][0])
    text = [ln for ln in dyn.read_text().splitlines() if ln.startswith("timestamp_motion_triggers:")][0]
    assert re.fullmatch(r"timestamp_motion_triggers: 0(,\d+)*", text)  # integers: what CASToR reads
    stamps = read_castor_keyword(dyn, "timestamp_motion_triggers")[0]
    params = read_castor_keyword(rig, "Transformation_parameters")
    assert n == len(r.states) == len(stamps) == len(params) == 3
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    assert params[0] == [0.0] * 6  # the state at the acquisition start: CASToR's reference
    assert rig.read_text().count("Rotation_convention: XYZ") == 1
    assert read_castor_keyword(rig, "Transformation_mode")[0] == [0.0]
    # each state starts at the whole second nearest its start (list-mode seconds)
    for s, stamp in zip(r.states[1:], stamps[1:]):
        assert abs(stamp - s.t_start) <= 0.5
    doc = json.loads((out / "motion_6dof.json").read_text())["castor"]
    assert doc["written"] and [ln["trigger_s"] for ln in doc["lines"]] == stamps and doc["merged"] == []


def castor_matrix_from_source_rules(p):
    """The 4x4 matrix CASToR 3.1.1's iDeformationRigid builds from one parameter line (written
    here from its source, not from our writer): Translation(-t) times Rx(rA) Ry(rB) Rz(rC)."""
    tx, ty, tz = p[:3]
    a, b, c = np.radians(p[3:])
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    trs = np.eye(4)
    trs[:3, 3] = [-tx, -ty, -tz]
    rot = np.eye(4)
    rot[:3, :3] = rx @ ry @ rz
    return trs @ rot


def test_castor_parameters_undo_the_true_pose_of_each_state(synced):
    """CASToR pulls: an output voxel at x takes the input at M x. For the image CASToR reconstructs
    (the patient as at the acquisition start) to be carried into a state's pose, M must take a
    point of that state back to where it was at the start -- in CASToR's image frame (x = SPECT X,
    y = SPECT Y, z = -SPECT Z; the scene's SPECT origin is the FOV centre, CASToR's image centre)."""
    patient, r, out, _, t0 = synced
    params = read_castor_keyword(out / "castor_motion_rigid.txt", "Transformation_parameters")
    flip = np.diag([1.0, 1.0, -1.0])
    R0, T0 = patient.body_transform(t0 - LEAD)  # the pose at the acquisition start
    x_start = np.array([[0.0, 0.0, 0.0], [100.0, 50.0, -80.0], [-120.0, 80.0, 150.0]])
    for s, p in zip(r.states, params):
        R, T = patient.body_transform(t0 - LEAD + 0.5 * (s.t_start + s.t_end))
        x_state = (x_start - T0) @ R0 @ R.T + T  # the start pose undone, the state's applied
        M = castor_matrix_from_source_rules(p)
        back = (x_state @ flip) @ M[:3, :3].T + M[:3, 3]
        assert np.abs(back - x_start @ flip).max() < 0.5, (s.index, back - x_start @ flip)


def test_six_dof_csv_and_json_agree_and_quaternions_match_the_angles(exported):
    _, r, out, _, _ = exported
    with open(out / "motion_6dof.csv") as f:
        rows = list(csv.DictReader(f))
    doc = json.loads((out / "motion_6dof.json").read_text())
    assert len(rows) == len(doc["columns"]["time_s"]) == len(r.pose.t)
    assert "host clock" in doc["clock"] and doc["frame"]["name"] == "SPECT frame"
    assert "X towards the patient's left" in doc["frame"]["definition"] and doc["frame"]["volume"] == SCENE_VOLUME
    ok = [k for k, row in enumerate(rows) if row["quality"] == "ok"][::50]
    assert len(ok) > 10
    for k in ok:
        e = [float(rows[k][c]) for c in ("rx_deg", "ry_deg", "rz_deg")]
        q = [float(rows[k][c]) for c in ("qx", "qy", "qz", "qw")]
        assert Rotation.from_quat(q).as_euler("xyz", degrees=True) == pytest.approx(e, abs=1e-3)
        assert float(rows[k]["tx_mm"]) == pytest.approx(doc["columns"]["tx_mm"][k], abs=1e-3)
    states = {int(row["state"]) for row in rows}
    assert states == {0, 1, 2}
    assert len(doc["events"]) == 2


def test_respiration_and_subsets(exported):
    patient, r, out, _, t0 = exported
    with open(out / "respiration.csv") as f:
        rows = list(csv.DictReader(f))
    amp = np.array([float(x["amplitude_mm"]) for x in rows])
    t = np.array([float(x["time_s"]) for x in rows]) + r.series.t[0]
    assert np.corrcoef(amp, patient.breathing.value(t))[0, 1] > 0.98
    sub = json.loads((out / "subsets.json").read_text())
    ms = sub["motion_states"]
    assert [s["state"] for s in ms] == [0, 1, 2]
    assert all(a["interval_s"][1] == pytest.approx(b["interval_s"][0]) for a, b in zip(ms, ms[1:]))
    for kind in ("amplitude", "phase"):
        bins = sub["respiratory_bins"][kind]
        assert len(bins) == 4 and all(b["frames"] > 0 and b["intervals"] for b in bins)
    # amplitude bins: equal frame counts within a few frames, and their amplitudes really differ
    counts = [b["frames"] for b in sub["respiratory_bins"]["amplitude"]]
    assert max(counts) - min(counts) <= 0.05 * sum(counts)
    lo = [b["amplitude_mm"][0] for b in sub["respiratory_bins"]["amplitude"]]
    assert lo == sorted(lo) and lo[-1] > lo[0]


def test_castor_writer_refuses_what_castor_would_misread(tmp_path):
    with pytest.raises(ValueError, match="without a pose"):
        write_castor([0, 5], [[0] * 6, [np.nan] * 6], tmp_path)
    with pytest.raises(ValueError, match="whole seconds"):
        write_castor([0, 8.5], [[0] * 6, [1, 2, 3, 0.5, 0, 0]], tmp_path)  # CASToR would read 8
    with pytest.raises(ValueError, match="whole seconds"):
        write_castor([3, 8], [[0] * 6, [1, 2, 3, 0.5, 0, 0]], tmp_path)  # CASToR refuses a first not 0
    with pytest.raises(ValueError, match="increase"):
        write_castor([0, 8, 8], [[0] * 6] * 3, tmp_path)  # CASToR would skip a line
    p1, p2 = write_castor([0, 8], [[0] * 6, [1, 2, 3, 0.5, 0, 0]], tmp_path, comment="a # note")
    assert read_castor_keyword(p1, "timestamp_motion_triggers") == [[0.0, 8.0]]
    assert p1.read_text().startswith("# a note\n") and p2.read_text().startswith("# a note\n")


def test_on_the_spect_clock_times_are_list_mode_seconds(synced):
    """Tracks with SPECT times (as the sync analysis makes them): every time in the exports is
    list-mode seconds, the CASToR triggers whole seconds from the acquisition start (list-mode 0)."""
    patient, r, out, paths, t0 = synced
    assert r.series.clock == "spect" and paths.notes == [] and (out / "yrtpet_lor_motion.csv") in paths
    doc = json.loads((out / "motion_6dof.json").read_text())
    assert "SPECT list-mode" in doc["clock"] and doc["time_origin"] == 0.0
    assert doc["columns"]["time_s"][0] == pytest.approx(LEAD, abs=1e-6)
    stamps = read_castor_keyword(out / "castor_motion.dyn", "timestamp_motion_triggers")[0]
    assert stamps[0] == 0.0
    moves = sorted(m.t_start for m in patient.motion.moves)
    for stamp, true_start in zip(stamps[1:], moves):
        assert true_start - t0 + LEAD - 1.0 <= stamp <= true_start - t0 + LEAD + 2.5


def read_lor_motion_by_yrtpet_rules(path):
    """YRT-PET's LORMotion::readFromFile (commit ec8cf3b), written here from its source, not from our
    writer: per non-empty line an unsigned 32-bit integer (from_chars: no sign, no fraction), then 12
    floats and the error, each after any run of ',' or ' '; anything after the error: the line is
    skipped. Returns (ms, (N, 3, 4), error) and the lines it would skip."""
    ms, mats, errs, skipped = [], [], [], []
    num = re.compile(r"[+-]?(\d+\.?\d*([eE][+-]?\d+)?|\.\d+([eE][+-]?\d+)?|inf|nan)", re.I)
    for k, line in enumerate(path.read_text(encoding="ascii").split("\n"), 1):
        if not line:
            continue
        m = re.match(r"\d+", line)
        if m is None or int(m.group()) > 2**32 - 1 or line[m.end() : m.end() + 1] not in (",", " ", ""):
            skipped.append(k)  # (a '.' after the digits would shift the columns)
            continue
        pos, vals = m.end(), []
        for _ in range(13):
            while pos < len(line) and line[pos] in ", ":
                pos += 1
            f = num.match(line, pos)
            if f is None or f.group().startswith("+"):
                break
            vals.append(float(f.group()))
            pos = f.end()
        if len(vals) != 13 or line[pos:].strip():
            skipped.append(k)
            continue
        ms.append(int(m.group()))
        mats.append(np.array(vals[:12]).reshape(3, 4))
        errs.append(vals[12])
    return np.array(ms), np.array(mats), np.array(errs), skipped


def test_yrtpet_lor_motion_undoes_the_true_pose_on_the_list_mode_clock(synced):
    """YRT-PET moves each event's LOR by its frame's [R|t] (p -> R p + t) so that the events land where
    they were in the reference pose. Carry points from motion_6dof's reference pose (the first still
    period) into the true body pose of a line's time; the line's matrix must bring them back."""
    patient, r, out, _, t0 = synced
    ms, M, e, skipped = read_lor_motion_by_yrtpet_rules(out / "yrtpet_lor_motion.csv")
    assert skipped == [] and not (out / "yrtpet_lor_motion.csv").read_text().startswith(("t", "#"))
    assert ms[0] == 0 and np.all(np.diff(ms) > 0) and ms[1] == round(LEAD * 1000)  # list-mode ms
    assert e[0] == 1.0 and np.all((e >= 0) & (e <= 1))  # no frame before 2.5 s: no pose there
    doc = json.loads((out / "motion_6dof.json").read_text())
    conf = np.array(doc["columns"]["confidence"])
    assert e[1:] == pytest.approx(1 - conf, abs=6e-5) and doc["yrtpet"]["lines"] == len(ms)
    a, b = r.reference_period
    R0, T0 = patient.body_transform(0.5 * (a + b) + t0 - LEAD)  # the reference pose (truth)
    x_ref = np.array([[0.0, 0.0, 0.0], [100.0, 50.0, -80.0], [-120.0, 80.0, 150.0]])
    worst = 0.0
    for k in range(1, len(ms), 37):
        R, T = patient.body_transform(ms[k] / 1000.0 + t0 - LEAD)
        x_now = (x_ref - T0) @ R0 @ R.T + T  # the reference pose undone, this one applied
        back = x_now @ M[k][:, :3].T + M[k][:, 3]
        worst = max(worst, float(np.abs(back - x_ref).max()))
    assert worst < 0.5, worst
    assert np.allclose(np.einsum("kij,kil->kjl", M[:, :, :3], M[:, :, :3]), np.eye(3), atol=1e-6)  # rotations


def test_every_pose_says_how_sure_it_is_in_the_exports(synced):
    _, r, out, _, _ = synced
    with open(out / "motion_6dof.csv") as f:
        rows = list(csv.DictReader(f))
    assert {row["health"] for row in rows} <= {"known", "bounded", "not known"}
    for row in rows:
        c = float(row["confidence"])
        assert 0.0 <= c <= 1.0
        assert (row["health"] == "not known") == (c == 0.0) == (row["quality"] in ("no pose", "no frames"))
        assert (row["health_why"] == "") == (row["health"] == "known")
    sub = json.loads((out / "subsets.json").read_text())
    for s in sub["motion_states"]:
        h = s["health"]
        assert sum(h["rows"].values()) > 0 and 0 < h["confidence_min"] <= h["confidence_mean"] <= 1
    assert all(b["confidence_mean"] > 0 for b in sub["respiratory_bins"]["amplitude"])
    assert sub["health"]["rows"]["known"] == sum(row["health"] == "known" for row in rows)


def test_yrtpet_writer_refuses_what_yrtpet_would_misread_and_targets_not_files(tmp_path):
    from vts_hw.files import NotReplaced
    from vts_hw.motion.yrtpet import LorMotionPlan, lor_motion_text, write_lor_motion

    eye = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0]
    with pytest.raises(ValueError, match="unsigned 32-bit"):
        lor_motion_text(np.array([-40, 0]), [eye, eye], [0, 0])
    with pytest.raises(ValueError, match="unsigned 32-bit"):
        lor_motion_text(np.array([0.0, 40.5]), [eye, eye], [0, 0])
    with pytest.raises(ValueError, match="increase"):
        lor_motion_text(np.array([0, 40, 40]), [eye] * 3, [0] * 3)
    with pytest.raises(ValueError, match="without a pose"):
        lor_motion_text(np.array([0, 40]), [eye, [np.nan] * 12], [0, 1])
    with pytest.raises(ValueError, match="between 0 and 1"):
        lor_motion_text(np.array([0]), [eye], [1.5])
    plan = LorMotionPlan(None, np.array([0, 40]), np.array([eye, eye], float), np.array([1.0, 0.25]))
    for kind in ("dir", "fifo"):
        node = tmp_path / kind / "yrtpet_lor_motion.csv"
        node.parent.mkdir()
        node.mkdir() if kind == "dir" else os.mkfifo(node)
        with pytest.raises(NotReplaced, match="yrtpet_lor_motion.csv"):
            write_lor_motion(node, plan)
    p = write_lor_motion(tmp_path / "ok.csv", plan)
    assert p.read_text().splitlines()[1] == "40," + ",".join(f"{v:.9f}" for v in eye) + ",0.250000000"


def test_a_fifo_or_folder_named_as_yrtpets_file_is_left_as_it_is(exported, synced, tmp_path):
    """A writer replaces only a regular file: on the host clock (no file to write) the FIFO is no
    earlier export's and is not removed; on the SPECT clock the export stops there in one sentence
    (exit 3 through the CLI), the FIFO kept, the files before it whole."""
    from vts_hw.files import NotReplaced

    host, spect = tmp_path / "host", tmp_path / "spect"
    for d in (host, spect):
        d.mkdir()
        os.mkfifo(d / "yrtpet_lor_motion.csv")
    paths = export_motion(exported[1], host, volume=SCENE_VOLUME)
    assert paths.notes[1].endswith(
        "(yrtpet_lor_motion.csv there is a named pipe (FIFO), no earlier export's file: left as it is)"
    )
    with pytest.raises(NotReplaced, match=r"yrtpet_lor_motion.csv: could not be written \(it is a named pipe"):
        export_motion(synced[1], spect, volume=SCENE_VOLUME)
    for d in (host, spect):
        assert (d / "yrtpet_lor_motion.csv").is_fifo()
    assert sorted(p.name for p in spect.iterdir()) == ["motion_6dof.csv", "yrtpet_lor_motion.csv"]
