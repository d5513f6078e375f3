"""Frames made ahead of time (sim_devices/frame_bank.py): streamed over HTTP through our driver,
they show the patient where the truth says at their stamps, moves included, once the stretch
has started playing; they come whole and on time while every core is busy; and anything the
bank cannot stand for (the LED off) is rendered live as before."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from vts_hw.drivers.axis_stream import FrameStream, StreamGap
from vts_hw.drivers.registry import open_camera
from vts_hw.sim_devices.patient import BAND_MARKERS, BodyMove, add_patient
from vts_hw.sim_devices.rig import SimRig
from vts_hw.vision.detect import detect_jpeg

BAND = set(BAND_MARKERS["chest"]) | set(BAND_MARKERS["abdomen"])
pytestmark = pytest.mark.timeout(300)  # a hang detector: making frames takes long on a loaded machine
SPIN = "import signal, sys\nsignal.signal(signal.SIGTERM, lambda *a: sys.exit(0))\nwhile True:\n    pass\n"


def _stream(rig, name: str, seconds: float | None = None, frames: int | None = None):
    with open_camera(rig.config().camera(name)) as cam:
        items = list(FrameStream(cam, duration=seconds, nbrofframes=frames))
    return [f for f in items if not isinstance(f, StreamGap)], [g for g in items if isinstance(g, StreamGap)]


def _rig_with_patient(move_in_s: float | None = None):
    rig = SimRig(n_cameras=2, seed=4).start()
    rig.ntp_sync()
    now = rig.clock.now()
    moves = (
        []
        if move_in_s is None
        else [BodyMove(now + move_in_s, now + move_in_s + 0.6, (0.0, 2.0, 0.0), (6.0, 4.0, 3.0))]
    )
    patient = add_patient(rig.scene, now, 120.0, seed=2, moves=moves)
    for src in rig.sources.values():
        src.set_led(True)
    return rig, patient


def test_frames_made_ahead_show_the_patient_where_the_truth_says(monkeypatch):
    rig, patient = _rig_with_patient(move_in_s=1.0)
    move = patient.motion.moves[0]
    planned = (move.t_start, patient.breathing.t0)
    played = []
    rig.on_play(played.append)
    try:
        stats = rig.prerender(3.0)
        bank_start = rig.bank.first / rig.fps
        monkeypatch.setattr(os, "environ", {**os.environ, **rig.env_vars()})
        frames, gaps = _stream(rig, "cam1", 2.5)
    finally:
        rig.stop()
    assert stats.frames == 2 * 75 and stats.ms_per_frame > 0 and 0 < stats.core_share
    assert gaps == [] and len(frames) >= 55 and rig.bank.served >= len(frames) and rig.bank.missed == {}
    # the stretch started playing at the stream's first frame: the patient's plan moved with it
    (dt,) = played
    first = rig.scene.clocks["cam1"].host_time(frames[0].camera_time)
    assert abs(first - (bank_start + dt)) < 0.011
    assert move.t_start == planned[0] + dt and patient.breathing.t0 == planned[1] + dt
    # every frame shows the band where the truth puts it at the frame's stamp: still, moving, after
    clock = rig.scene.clocks["cam1"]
    during = [f for f in frames if move.t_start + 0.1 < clock.host_time(f.camera_time) + 0.005 < move.t_end - 0.1]
    assert during
    for f in (frames[2], during[len(during) // 2], frames[-2]):
        blobs = np.array([(b.x, b.y) for b in detect_jpeg(f.jpeg).blobs])
        t = clock.host_time(f.camera_time) + 0.005  # the stamp is truncated to 10 ms
        truth = {k: np.array((u, v)) for k, u, v in rig.scene.truth("cam1", t) if k in BAND}
        assert len(truth) >= 6
        for k, uv in truth.items():
            assert np.linalg.norm(blobs - uv, axis=1).min() < 0.8, (k, t - move.t_start)


def test_a_rewound_stretch_plays_again_from_the_next_stream_with_the_patient_moved_back(monkeypatch):
    rig, patient = _rig_with_patient(move_in_s=1.0)
    move = patient.motion.moves[0]
    planned = (move.t_start, patient.breathing.t0)
    played = []
    rig.on_play(played.append)
    try:
        rig.prerender(2.0)
        monkeypatch.setattr(os, "environ", {**os.environ, **rig.env_vars()})
        first, _ = _stream(rig, "cam1", frames=10)
        rig.bank.rewind()
        assert (move.t_start, patient.breathing.t0) == pytest.approx(planned) and not rig.bank.playing
        assert rig.bank.served == 0
        time.sleep(0.3)
        again, _ = _stream(rig, "cam1", frames=10)
    finally:
        rig.stop()
    assert len(played) == 2 and played[1] > played[0] + 0.2  # started anew, later
    assert move.t_start == pytest.approx(planned[0] + played[1]) and rig.bank.served == 10
    assert rig.bank.missed == {}
    # the second stream shows the patient where the truth (moved by the second start) says
    clock = rig.scene.clocks["cam1"]
    f = again[5]
    blobs = np.array([(b.x, b.y) for b in detect_jpeg(f.jpeg).blobs])
    t = clock.host_time(f.camera_time) + 0.005
    truth = {k: np.array((u, v)) for k, u, v in rig.scene.truth("cam1", t) if k in BAND}
    assert len(truth) >= 6
    for k, uv in truth.items():
        assert np.linalg.norm(blobs - uv, axis=1).min() < 0.8, k


def test_frames_made_ahead_come_whole_and_on_time_while_every_core_is_busy(monkeypatch):
    rig, _ = _rig_with_patient()
    load = []
    try:
        rig.prerender(6.0)
        monkeypatch.setattr(os, "environ", {**os.environ, **rig.env_vars()})
        load = [subprocess.Popen([sys.executable, "-c", SPIN]) for _ in range(2 * (os.cpu_count() or 2))]
        got = {}
        threads = [
            threading.Thread(target=lambda n=n: got.__setitem__(n, _stream(rig, n, 4.0))) for n in ("cam1", "cam2")
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        for p in load:
            p.terminate()
        for p in load:
            p.wait()
        rig.stop()
    for name, (frames, gaps) in got.items():
        assert gaps == [], (name, [g.reason for g in gaps])  # not one frame skipped
        steps = [b.camera_time - a.camera_time for a, b in zip(frames, frames[1:])]
        assert len(frames) >= 85 and max(steps) < 0.05, name
        clock = rig.scene.clocks[name]
        late = sorted(f.host_time - clock.host_time(f.camera_time) for f in frames)
        assert late[len(late) // 2] < 0.25, (name, late[len(late) // 2])  # and sent when their time came


def test_what_the_bank_cannot_stand_for_is_rendered_live(monkeypatch):
    rig, _ = _rig_with_patient()
    try:
        rig.prerender(2.0)
        rig.sources["cam2"].set_led(False)  # the frames were made with the LED on
        monkeypatch.setattr(os, "environ", {**os.environ, **rig.env_vars()})
        lit, _ = _stream(rig, "cam1", frames=10)
        dark, _ = _stream(rig, "cam2", frames=10)
    finally:
        rig.stop()
    assert rig.bank.missed == {"LED off": 10} and rig.bank.served == 10
    assert len(detect_jpeg(lit[5].jpeg).blobs) >= 6 > len(detect_jpeg(dark[5].jpeg).blobs)
