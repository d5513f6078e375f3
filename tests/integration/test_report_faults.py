"""The drift report never overstates, and `vts report drift` fails in one sentence.

- A simulated rig as a user drives it (`vts sim up --detach` as a subprocess, `vts qa drift`,
  `vts report drift` in this process as the console script runs them): runs without a baseline, then a baseline and two runs minutes apart:
  no trend, no forecast, the reason in words, axes scaled to the runs and the bands.
- The PDF's words, read back by poppler's pdftotext, all lie on the page and never overlap.
- A real full disk (a small tmpfs): the report is not half-written, the previous one stays.
- Absurd --since values, an empty store, an old run note holding a Python class name, the
  sync report's banner with nothing wrong.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from inprocess_cli import run
from test_report import NOW, populate
from vts_hw.report import build_drift_report, collect
from vts_hw.report.plots import camera_figure
from vts_hw.report.sync_html import render_sync_html
from vts_hw.report.trend import DAY
from vts_hw.sim_devices.rig import load_env_file
from vts_hw.store import ResultsStore
from vts_hw.tolerance import DEFAULT_TOLERANCES

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]
OLD_NOTE = "NoBaseline: camera cam1 has no drift baseline in the results store: run `vts qa drift --set-baseline` first"


def vts(*args, env=None) -> subprocess.CompletedProcess:
    """`vts ARGS` in this process (tests/inprocess_cli.py): what is checked is what it says,
    writes and stores, and its exit code."""
    return run(*args, env=env)


def vts_process(*args) -> subprocess.CompletedProcess:
    """`vts ARGS` as its own process: `vts sim up --detach` leaves its rig running after it."""
    return subprocess.run([*VTS, *args], capture_output=True, text=True, timeout=120)


def one_sentence(p: subprocess.CompletedProcess) -> str:
    """The stderr of a failed command: one line starting `vts: `, no traceback."""
    err = p.stderr.strip()
    assert "Traceback" not in p.stderr and len(err.splitlines()) == 1 and err.startswith("vts: "), p.stderr
    return err


def pdf_words(path: Path) -> list[tuple[float, float, list[tuple[float, float, float, float, str]]]]:
    """Per page: width, height and every word with its box, from `pdftotext -bbox`."""
    out = subprocess.run(["pdftotext", "-bbox", str(path), "-"], capture_output=True, text=True, check=True).stdout
    pages = []
    for m in re.finditer(r'<page width="([\d.]+)" height="([\d.]+)">(.*?)</page>', out, re.S):
        words = [
            (float(a), float(b), float(c), float(d), w)
            for a, b, c, d, w in re.findall(
                r'<word xMin="([-\d.]+)" yMin="([-\d.]+)" xMax="([-\d.]+)" yMax="([-\d.]+)">(.*?)</word>', m.group(3)
            )
        ]
        pages.append((float(m.group(1)), float(m.group(2)), words))
    assert pages, out[:500]
    return pages


def overlaps(words) -> list[tuple[str, str]]:
    """Pairs of words whose boxes overlap by more than half a point both ways."""
    bad = []
    for i, (a0, b0, a1, b1, w) in enumerate(words):
        for c0, d0, c1, d1, v in words[i + 1 :]:
            if min(a1, c1) - max(a0, c0) > 0.5 and min(b1, d1) - max(b0, d0) > 0.5:
                bad.append((w, v))
    return bad


def assert_pdf_fits(path: Path, overlap_pages=(0,)) -> list:
    pages = pdf_words(path)
    for n, (w, h, words) in enumerate(pages):
        outside = [x for x in words if x[0] < 0 or x[1] < 0 or x[2] > w or x[3] > h]
        assert not outside, (n + 1, outside[:5])
    for n in overlap_pages:
        assert not overlaps(pages[n][2]), (n + 1, overlaps(pages[n][2])[:5])
    return pages


def rig_yaml(folder: Path, store: Path) -> Path:
    cfg = folder / "rig.yaml"
    cfg.write_text(f"rig: vts\ncameras:\n  - name: cam1\n    host: 127.0.0.1\nresults:\n  url: sqlite:///{store}\n")
    return cfg


# --- a simulated rig, as a user drives it -------------------------------------------------


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    p = vts_process("sim", "up", "--detach", "--dir", str(d))
    assert p.returncode == 0, p.stderr
    with open(d / "rig.yaml", "a") as f:
        f.write(f"store:\n  url: sqlite:///{d / 'results.sqlite'}\n")  # (sim up wrote one: the last wins)
    env = dict(os.environ)
    env.update(load_env_file(d / "sim.env"))
    yield d, env
    vts_process("sim", "down", "--dir", str(d))


def _report_json(d: Path, env, out: Path) -> dict:
    p = vts("report", "drift", "--since", "60d", "-o", str(out), "--json", env=env)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


@pytest.mark.timeout(300)
def test_no_baseline_then_two_runs_minutes_apart(sim):
    d, env = sim
    # a run without a baseline stops before anything is written (exit 5, in words); the report
    # says a baseline is needed
    p = vts("qa", "drift", env=env)
    assert p.returncode == 5 and "set-baseline" in p.stderr and not re.search(r"\bNoBaseline\b", p.stderr)
    data = _report_json(d, env, d / "none.html")
    assert data["cameras"] == {} and data["has_baseline"] is False and data["not_completed"] == []
    assert any("no drift baseline is recorded" in a for a in data["attention"])
    html = (d / "none.html").read_text()
    assert "NoBaseline" not in html and "set-baseline" in html

    # a baseline and two runs minutes apart
    for args in (("--set-baseline",), (), ()):
        p = vts("qa", "drift", *args, env=env)
        assert p.returncode in (0, 10, 20), p.stderr
    data = _report_json(d, env, d / "r.pdf")
    assert set(data["cameras"]) == {"cam1", "cam2"}
    for cam in data["cameras"].values():
        for axis in ("x", "y"):
            a = cam["axes"][axis]
            assert a["trend"]["slope_per_30d"] is None and a["forecast"]["status"] == "no fit"
            assert a["trend"]["reason"] == "2 runs over 0.0 days: a trend needs 5 runs over 7 days"
    assert not any("action level" in a for a in data["attention"]), data["attention"]
    assert "5 runs over 7 days" in data["trend_rule"]

    # the PDF says it in words and fits its pages
    pages = assert_pdf_fits(d / "r.pdf")
    text = subprocess.run(["pdftotext", "-layout", str(d / "r.pdf"), "-"], capture_output=True, text=True).stdout
    assert "no trend yet: 2 runs over 0.0 days: a trend needs 5 runs over 7 days" in text
    assert len(pages) == 3
    html_data = _report_json(d, env, d / "r.html")
    html = (d / "r.html").read_text()
    assert "none yet" in html and "2 runs over 0.0 days" in html and html_data["state"] in ("OK", "TOLERANCE", "ACTION")

    # axes: the drift axis spans the action levels with a margin (not hundreds of px), the
    # time axis the minutes of the runs (not the 60 days asked for)
    with ResultsStore(f"sqlite:///{d / 'results.sqlite'}") as store:
        report = collect(store, rig="sim")
    for cam in report.cameras.values():
        fig = camera_figure(report, cam)
        ax_x, ax_y = fig.axes[0], fig.axes[1]
        for ax in (ax_x, ax_y):
            lo, hi = ax.get_ylim()
            assert -2.6 < lo < -2.0 and 2.0 < hi < 2.6, (cam.name, lo, hi)
        t0, t1 = ax_x.get_xlim()
        assert t1 - t0 < 1.0, t1 - t0  # matplotlib dates: days


# --- the PDF fits its pages ---------------------------------------------------------------


def test_pdf_summary_table_fits_with_many_long_rows(tmp_path):
    """Eight cameras with long names, noisy steep drifts (wide slope texts), LED failures
    (the longest LED text): every word on the page, no two words on top of each other."""
    rng = np.random.default_rng(5)
    t0 = NOW - 9 * DAY
    names = [f"camera-{side}-wall-{i}" for side in ("north", "south") for i in range(1, 5)]
    with ResultsStore(f"sqlite:///{tmp_path / 's.sqlite'}") as s:
        for metric, w in DEFAULT_TOLERANCES.items():
            s.set_tolerance(metric, w, effective_from=t0 - DAY)
        s.begin_run("drift-baseline", rig="vts", started=t0 - 3600).finish(finished=t0 - 3500)
        for day in range(9):
            h = s.begin_run("daily", rig="vts", started=t0 + day * DAY)
            for k, cam in enumerate(names):
                h.measure(cam, "drift_x_px", float(rng.normal(0.3 * k * day / 9, 3.0)), "px")
                h.measure(cam, "drift_y_px", float(rng.normal(-0.2 * k * day, 0.05)), "px")
                h.measure(cam, "drift_x_mm", 0.0, "mm")
                h.measure(cam, "drift_y_mm", 0.0, "mm")
                h.measure(cam, "led_off_visible", 3 if day in (2, 5) else 0)
            h.finish(finished=t0 + day * DAY + 60)
        report = build_drift_report(s, tmp_path / "many.pdf", now=NOW, rig="vts")
    assert len(report.cameras) == 8
    pages = assert_pdf_fits(tmp_path / "many.pdf")
    first = " ".join(w[4] for w in pages[0][2])
    for name in names:
        assert name in first  # every row is on the title page
    assert "n.s." in first and "failed" in first


def test_the_60_day_report_fits_its_pages(tmp_path):
    with ResultsStore(f"sqlite:///{tmp_path / 's.sqlite'}") as s:
        populate(s)
        build_drift_report(s, tmp_path / "r.pdf", now=NOW, rig="vts")
    assert_pdf_fits(tmp_path / "r.pdf", overlap_pages=(0,))


# --- old notes, the sync banner -----------------------------------------------------------


def test_an_old_note_with_a_class_name_reads_plainly(tmp_path):
    """A run stored by an older version, aborted with "aborted: NoBaseline: ...": the store
    keeps it as it is, the report shows it without the Python name."""
    with ResultsStore(f"sqlite:///{tmp_path / 's.sqlite'}") as s:
        h = s.begin_run("drift", rig="vts", started=NOW - 3600)
        h.abort(OLD_NOTE)
        h = s.begin_run("daily", rig="vts", started=NOW - 1800)
        h.abort("KeyboardInterrupt")
        assert s.run(h.run_id).notes == "aborted: KeyboardInterrupt"  # history unchanged
        html = build_drift_report(s, tmp_path / "r.html", now=NOW).out.read_text()
        data = build_drift_report(s, tmp_path / "r.pdf", now=NOW).results_data()
    notes = [r["notes"] for r in data["not_completed"]]
    assert notes == [
        "aborted: camera cam1 has no drift baseline in the results store: run `vts qa drift --set-baseline` first",
        "aborted: interrupted (Ctrl-C)",
    ]
    assert data["not_completed"][0]["stored_notes"] == "aborted: " + OLD_NOTE
    pdf = subprocess.run(["pdftotext", str(tmp_path / "r.pdf"), "-"], capture_output=True, text=True).stdout
    for text in (html, pdf):
        assert "NoBaseline" not in text and "KeyboardInterrupt" not in text
        assert "has no drift baseline" in text


def _sync_data(problems: list[str], max_dt: float) -> dict:
    """A sync check's data as the analysis gives it, its verdict from the tolerance table."""
    from vts_hw.procedures.sync_verdict import sync_verdict, sync_windows

    summary = {
        "events": 3,
        "events_both": 3,
        "events_spect_only": 0,
        "events_vts_only": 0,
        "offset_s": 0.002,
        "spread_sd_s": 0.003,
        "max_abs_dt_s": max_dt,
        "start_delay_s": 0.01,
        "start_delay_modulo_s": 1.0,
        "spect_clock_offset_s": 0.1,
        "spect_skew_ppm": 3.0,
    }
    state, reason = sync_verdict(summary, problems=problems)
    summary.update(state=state.value, state_reason=reason)
    return {
        "summary": summary,
        "windows": {m: w.as_dict() for m, w in sync_windows().items()},
        "events": [],
        "trigger": {"start_host": 0.0, "device": "triggerbox", "period_s": 1.0, "duty": 0.5, "how": "the box's clock"},
        "gating": {"rising_edges": 20, "falling_edges": 20, "gate_low_v": 0.0, "gate_high_v": 5.0, "fit_rms_s": 0.0001},
        "dead_time_host": [],
        "vts": {"markers": [1], "trace": "SPECT Z", "samples": 500, "gaps_host": []},
        "calibration": {"stereo": "cal.json", "spect": "map.json"},
        "problems": problems,
        "session": "scan1",
        "listmode": "scan1.vtslm",
    }


def test_sync_banner_says_no_problems_in_words():
    ok = render_sync_html(_sync_data([], 0.004), b"")
    banner = re.search(r'<section class="card banner OK">(.*?)</section>', ok, re.S).group(1)
    assert "None." not in banner and "<li>" not in banner
    assert "every one of the 3 event(s) agrees within 20 ms; no problems found." in banner
    tol = render_sync_html(_sync_data(["cam1: a gap of 5.0 s"], 0.045), b"")
    banner = re.search(r'<section class="card banner TOLERANCE">(.*?)</section>', tol, re.S).group(1)
    assert "more than the 20 ms goal" in banner and "<li>cam1: a gap of 5.0 s</li>" in banner


# --- the command line: bad --since, an empty store, a full disk -------------------------------


@pytest.mark.parametrize(
    "since,words",
    [
        ("1000000d", "reaches back before 1970-01-01"),
        ("99999999999999999999w", "reaches back before 1970-01-01"),
        ("-5d", "expected a duration such as 12h, 60d or 8w"),
        ("sixty days", "expected a duration such as 12h, 60d or 8w"),
        ("0001-01-01", "is before 1970-01-01"),
        ("9999-12-31", "is in the future"),
    ],
)
def test_absurd_since_is_one_sentence_and_exit_2(tmp_path, since, words):
    env = dict(os.environ, VTS_CONFIG=str(rig_yaml(tmp_path, tmp_path / "s.sqlite")))
    p = vts("report", "drift", "--since", since, "-o", str(tmp_path / "r.html"), env=env)
    assert p.returncode == 2
    err = one_sentence(p)
    assert err.startswith("vts: --since ") and words in err, err
    assert not (tmp_path / "r.html").exists()


def test_bad_output_suffix_is_one_sentence_and_exit_2(tmp_path):
    env = dict(os.environ, VTS_CONFIG=str(rig_yaml(tmp_path, tmp_path / "s.sqlite")))
    p = vts("report", "drift", "-o", str(tmp_path / "r.txt"), env=env)
    assert p.returncode == 2 and "is written as .html or .pdf" in one_sentence(p)


@pytest.mark.parametrize("name", ["r.html", "r.pdf"])
def test_empty_store_writes_a_report_that_says_so(tmp_path, name):
    env = dict(os.environ, VTS_CONFIG=str(rig_yaml(tmp_path, tmp_path / "empty.sqlite")))
    ResultsStore(tmp_path / "empty.sqlite").close()  # a store without runs (a report makes none)
    p = vts("report", "drift", "--since", "all", "-o", str(tmp_path / name), env=env)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == f"wrote {tmp_path / name} (no completed drift runs in the period)"
    if name.endswith(".html"):
        assert "No completed drift runs in this period." in (tmp_path / name).read_text()
    else:
        text = subprocess.run(["pdftotext", str(tmp_path / name), "-"], capture_output=True, text=True).stdout
        assert "No completed drift runs in this period." in text


@pytest.mark.parametrize("name", ["drift.html", "drift.pdf"])
def test_disk_full_keeps_the_previous_report(tmp_path, small_disk, name):
    store = tmp_path / "s.sqlite"
    with ResultsStore(f"sqlite:///{store}") as s:
        populate(s)
    env = dict(os.environ, VTS_CONFIG=str(rig_yaml(tmp_path, store)))
    disk = small_disk(1024)
    out = disk.path / name
    p = vts("report", "drift", "--since", "all", "-o", str(out), env=env)
    assert p.returncode == 0, p.stderr  # it fits while there is room
    previous = out.read_bytes()
    assert len(previous) > 20_000
    disk.fill(leave=4096)
    p = vts("report", "drift", "--since", "30d", "-o", str(out), env=env)
    assert p.returncode == 3
    err = one_sentence(p)
    assert err == f"vts: {out}: could not be written (no space left on device); the previous version is unchanged"
    assert out.read_bytes() == previous
    assert disk.files() == {name: len(previous)}  # no .tmp, no 0-byte file
    # a new file on the full disk: nothing is left there
    p = vts("report", "drift", "-o", str(disk.path / f"new-{name}"), env=env)
    assert p.returncode == 3 and "nothing was written there" in one_sentence(p)
    assert disk.files() == {name: len(previous)}


def test_a_summary_too_long_for_one_page_goes_on_over_more(tmp_path):
    """40 cameras: the table goes on over "summary (continued)" pages, each row once, every
    word on its page, no two words overlapping."""
    from vts_hw.report.pdf import pdf_bytes, title_pages

    names = [f"cam{i}" for i in range(1, 41)]
    with ResultsStore(f"sqlite:///{tmp_path / 's.sqlite'}") as s:
        s.begin_run("drift-baseline", rig="vts", started=NOW - 2 * DAY).finish(finished=NOW - 2 * DAY + 60)
        h = s.begin_run("daily", rig="vts", started=NOW - DAY)
        for cam in names:
            h.measure(cam, "drift_x_px", 0.1, "px")
            h.measure(cam, "drift_y_px", -0.1, "px")
        h.finish(finished=NOW - DAY + 60)
        report = collect(s, now=NOW, rig="vts")
    pages = title_pages(report)
    assert len(pages) >= 2
    (tmp_path / "title.pdf").write_bytes(pdf_bytes(pages))
    read = assert_pdf_fits(tmp_path / "title.pdf", overlap_pages=range(len(pages)))
    words = [w[4] for _, _, ws in read for w in ws]
    assert sorted(w for w in words if re.fullmatch(r"cam\d+", w)) == sorted(names)
    assert "(continued)" in words and words.count("Camera") == len(pages)
