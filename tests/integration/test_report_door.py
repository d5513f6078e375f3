"""Reports by one door (issue 22 §5): one table of renderers by suffix serves every report, every
report exists as .html and .pdf, and a report asked for in another format is one sentence and
exit 2 before anything is read. The sync and motion PDFs say what their HTML says, every word
on its page and none over another (read back by poppler's pdftotext)."""

from __future__ import annotations

import re
import subprocess
import sys

import matplotlib
import pytest
from matplotlib.figure import Figure

from motion_truth import patient_tracks
from test_report_faults import _sync_data, assert_pdf_fits, one_sentence, vts
from vts_hw.figures import figure_png
from vts_hw.procedures.motion import MotionAnalysis
from vts_hw.report.motion_html import render_motion_html
from vts_hw.report.renderers import FORMATS, RENDERERS, ReportError, report_format, write_report
from vts_hw.report.sync_html import render_sync_html

matplotlib.use("Agg")


def _png() -> bytes:
    fig = Figure(figsize=(8, 3))
    fig.add_subplot().plot([0, 1, 2], [0, 1, 0])
    return figure_png(fig)


def _text(pages) -> str:
    return " ".join(w[4] for _, _, words in pages for w in words)


def test_every_report_has_a_renderer_for_every_suffix():
    assert set(RENDERERS) == {"drift", "drift-every-rig", "department", "sync", "motion", "commission"}
    for name, by_suffix in RENDERERS.items():
        assert tuple(by_suffix) == FORMATS, name
        assert all(callable(f.target()) for f in by_suffix.values()), name  # each names a function
    assert [report_format(n) for n in ("a.html", "a.HTM", "b.Pdf")] == [".html", ".html", ".pdf"]
    with pytest.raises(ReportError, match=r"r\.txt: the report is written as \.html or \.pdf, not \.txt"):
        report_format("r.txt")


def test_the_sync_report_as_pdf_says_what_the_html_says(tmp_path):
    data = _sync_data(["cam1: a gap of 5.0 s"], 0.045)
    data["events"] = [
        {
            "event": i,
            "t_rel_s": 2.0 + i,
            "t_list_s": 1.5 + i,
            "step_spect_mm": 10.0,
            "step_vts_mm": 9.8,
            "seen_by": "both",
            "dt_s": 0.004 * i,
            "vts_fit": {"t_err_s": 0.001},
            "spect_fit": {"t_err_s": 0.002},
            "note": "",
        }
        for i in range(1, 61)
    ]  # over a page
    png = _png()
    html = write_report("sync", tmp_path / "s.html", data, png).read_text()
    stamp = re.compile(r"generated [\d-]+ [\d:]+")  # the one line that differs
    assert stamp.sub("", html) == stamp.sub("", render_sync_html(data, png))
    pdf = write_report("sync", tmp_path / "s.pdf", data, png)
    raw = pdf.read_bytes()
    assert raw.startswith(b"%PDF") and b"/Subtype /Image" in raw  # the plot is in it
    pages = assert_pdf_fits(pdf, overlap_pages=range(3))
    assert len(pages) >= 3  # the long table went on
    words = _text(pages)
    for said in (
        "TOLERANCE",
        "more than the 20 ms goal",
        "cam1: a gap of 5.0 s",
        "offset VTS − SPECT",
        "Motion events",
        "+240.0",
        "Gating and dead time",
        "triggerbox",
        "SPECT Z",
        "(continued)",
    ):
        assert said.split()[0] in words and all(w in words for w in said.split()), said


def test_the_motion_report_as_pdf_says_what_the_html_says(tmp_path):
    _, tracks, _, _ = patient_tracks(seed=5, duration_s=40.0, n_moves=1)
    a = MotionAnalysis(tmp_path / "session", tracks=tracks).analyze()
    data, png = a.results_data(), a.plot()
    html = write_report("motion", tmp_path / "m.htm", data, png).read_text()
    assert html == render_motion_html(data, png)
    pdf = write_report("motion", tmp_path / "m.pdf", data, png)
    assert pdf.read_bytes().startswith(b"%PDF")
    pages = assert_pdf_fits(pdf, overlap_pages=range(1))
    words = _text(pages)
    s = data["summary"]
    for said in (
        s["state"],
        "pose known",
        f"{100 * s['motion_pose_coverage']:.1f}",
        "Body-motion events",
        "Motion states",
        "Markers and cameras",
        "chest",
        "abdomen",
        "motion_pose_coverage",
    ):
        assert all(w in words for w in said.split()), said


@pytest.mark.parametrize("command", ["sync", "motion"])
def test_an_analysis_report_in_another_format_is_refused_before_anything_is_read(tmp_path, command):
    p = vts(command, "analyze", str(tmp_path / "no-such-session"), "-o", str(tmp_path / "r.txt"))
    assert p.returncode == 2
    assert "r.txt: the report is written as .html or .pdf, not .txt" in one_sentence(p)
    assert not (tmp_path / "r.txt").exists()


@pytest.mark.parametrize(
    "argv, code",
    [
        (["report", "drift", "-o", "r.txt"], "2"),
        (["report", "rooms", "-o", "r.doc"], "2"),
        (["sync", "analyze", "no-such-session", "--listmode", "x.vtslm"], "3"),
    ],
)
def test_a_bad_input_is_said_before_the_plotting_and_fitting_libraries_load(tmp_path, argv, code):
    """The renderers are imported when a report is written (renderers.Renderer) and the packages
    give their names on first use (vts_hw.lazy): a bad -o or session is said at once."""
    prog = (
        "import sys\nfrom vts_hw.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n"
        "    heavy = sorted(m for m in ('matplotlib', 'scipy.stats', 'scipy.optimize', 'fontTools') if m in sys.modules)\n"
        "    print(e.code, heavy)\n"
    )
    p = subprocess.run([sys.executable, "-c", prog, *argv], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert p.stdout.split(None, 1) == [code, "[]\n"], (p.stdout, p.stderr)
    assert p.stderr.startswith("vts: ") and p.stderr.count("\n") == 1, p.stderr
