"""Bands and markers named as a person says them (issue 21, part A 5): the chest and abdomen bands
when the geometry says which (the SPECT frame: the band nearer the head end is the chest), and a
marker tracked in pieces is "marker 3 (26 track pieces)", never "10+22+32+..."."""

from __future__ import annotations

import dataclasses
import re

import numpy as np

from motion_truth import patient_tracks
from vts_hw.motion.bands import band_names
from vts_hw.motion.markers import MarkerSeries
from vts_hw.procedures.motion import MotionAnalysis
from vts_hw.report.motion_html import render_motion_html


def test_the_simulated_patients_bands_are_named_chest_and_abdomen(tmp_path):
    patient, tracks, truth, _ = patient_tracks(seed=5, duration_s=40.0, n_moves=1)
    a = MotionAnalysis(tmp_path / "session", tracks=tracks).analyze()
    d = a.results_data()
    assert sorted(b["band"] for b in d["bands"]) == ["abdomen", "chest"]
    assert "head end" in d["band_naming"]
    for m in d["markers"]:
        if m["patient"]:  # the truth: C1..C4 on the chest, A1..A4 on the abdomen
            true = truth["ids"][m["track_ids"][0]]
            assert m["band"] == {"C": "chest", "A": "abdomen"}[true[0]], (m, true)
        assert re.fullmatch(r"marker \d+( \(\d+ track pieces\))?", m["marker"]), m["marker"]
    text = a.results()
    assert (
        "chest: marker" in text
        and "abdomen: marker" in text
        and "+" not in text.split("patient markers")[1].split("\n")[0]
    )
    html = render_motion_html(d, a.plot())
    assert "<td>chest</td>" in html and "<td>abdomen</td>" in html


def test_in_the_vts_frame_the_bands_keep_numbers_and_say_why(tmp_path):
    _, tracks, _, _ = patient_tracks(seed=5, duration_s=40.0, n_moves=0)
    tracks = dataclasses.replace(tracks, xyz_spect=None)
    d = MotionAnalysis(tmp_path / "session", tracks=tracks).analyze().results_data()
    assert sorted(b["band"] for b in d["bands"]) == ["band 1", "band 2"]
    assert "VTS frame" in d["band_naming"] and "head end is not known" in d["band_naming"]


def test_band_names_need_two_bands_apart_along_the_table():
    chest, abdomen = np.array([0.0, 100.0, -100.0]), np.array([0.0, 90.0, 120.0])
    assert band_names([abdomen, chest], "spect")[0] == ["abdomen", "chest"]
    assert band_names([chest, abdomen], "vts")[0] == ["band 1", "band 2"]
    assert band_names([chest], "spect")[0] == ["band 1"]
    side = np.array([200.0, 100.0, -90.0])  # side by side: 10 mm apart along the table
    names, why = band_names([chest, side], "spect")
    assert names == ["band 1", "band 2"] and "not clear" in why


def test_a_marker_tracked_in_pieces_is_labelled_by_its_number():
    ids = [[7], [10, 22, 32, 40]]
    s = MarkerSeries(np.arange(3.0), np.zeros((3, 2, 3)), ids, numbers=[1, 2])
    assert s.label(0) == "marker 1" and s.label(1) == "marker 2 (4 track pieces)"
    assert s.subset([1]).label(0) == "marker 2 (4 track pieces)"  # a subset keeps the numbers
