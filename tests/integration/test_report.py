"""The drift trend report, built from a real ResultsStore on a temporary SQLite file.

The store is filled with 60 simulated days of QA runs with a known truth: cam2 drifts
0.02 px/day in y from the latest baseline, cam1 is flat; a baseline on day 10 resets the
drift; the drift windows tighten on day 35; one run aborts; the LED fails once. The HTML
report is opened in a real browser (Debian's chromium, headless) to prove the plots render.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from vts_hw.report import BadSince, ReportError, build_drift_report, collect, parse_since
from vts_hw.report.trend import DAY, control_limits, fit_trend, forecast
from vts_hw.store import ResultsStore
from vts_hw.tolerance import DEFAULT_TOLERANCES, Window

T0 = dt.datetime(2026, 7, 1, tzinfo=dt.UTC).timestamp()
N_DAYS = 60
NEW_BASELINE_DAY = 10
WINDOW_CHANGE_DAY = 35
ABORTED_DAY = 40
LED_FAIL_DAY = 45
MISSING_MARKER_DAY = 50
STRAY_BLOB_DAY = 52
CAM2_Y_SLOPE = 0.02  # px/day since the day-10 baseline
CAM2_X_SLOPE = 0.003  # px/day: far from any limit within a year
NOW = T0 + (N_DAYS - 1) * DAY + 12 * 3600
OLD_WINDOW = Window.symmetric(1.0, 2.0, "px")
NEW_WINDOW = Window.symmetric(0.75, 1.5, "px")
WINDOW_CHANGE_T = T0 + WINDOW_CHANGE_DAY * DAY + 10 * 3600  # after that day's run
BASELINE_T = T0 + NEW_BASELINE_DAY * DAY + 6.5 * 3600
MM_PER_PX = 1.25

CHROMIUM_HELP = (
    "chromium is not installed: install the Debian package with "
    "`apt-get install -y --no-install-recommends chromium` (make test does this)"
)


def _truth(cam: str, t: float) -> tuple[float, float]:
    """The true drift (x, y) in px of a camera at time t."""
    if cam == "cam1":
        return 0.0, 0.0
    if t < BASELINE_T:  # before the new baseline: drifting from the old one, already large
        d = (t - T0) / DAY
        return 0.2 + 0.01 * d, 0.6 + 0.05 * d
    d = (t - BASELINE_T) / DAY
    return CAM2_X_SLOPE * d, CAM2_Y_SLOPE * d


def populate(store: ResultsStore, seed: int = 7) -> None:
    """60 days of drift QA on two cameras (see the module docstring)."""
    rng = np.random.default_rng(seed)
    start = T0 - 30 * DAY
    for metric, w in DEFAULT_TOLERANCES.items():
        store.set_tolerance(metric, w, effective_from=start, note="defaults")
    for metric in ("drift_x_px", "drift_y_px"):
        store.set_tolerance(metric, OLD_WINDOW, effective_from=start)
        store.set_tolerance(metric, NEW_WINDOW, effective_from=WINDOW_CHANGE_T, note="tightened")

    for day in (0, NEW_BASELINE_DAY):
        h = store.begin_run("drift-baseline", rig="vts", operator="physicist", started=T0 + day * DAY + 6.5 * 3600)
        for cam in ("cam1", "cam2"):
            h.measure(cam, "markers_found", 5, status="OK")
        h.finish(finished=T0 + day * DAY + 6.6 * 3600)

    for day in range(N_DAYS):
        t = T0 + day * DAY + 7 * 3600 + float(rng.uniform(0, 1200))
        procedure = "drift" if day % 7 == 3 else "daily"
        if day == ABORTED_DAY:
            h = store.begin_run(procedure, rig="vts", operator="physicist", started=t)
            h.measure("cam1", "drift_x_px", 0.0)
            h.abort("camera cam2 did not answer (HTTP 503 too many viewers)")
            t += 1800  # repeated half an hour later
        h = store.begin_run(procedure, rig="vts", operator="physicist", started=t)
        for cam in ("cam1", "cam2"):
            tx, ty = _truth(cam, t)
            x = tx + rng.normal(0, 0.03)
            y = ty + rng.normal(0, 0.03)
            h.measure(cam, "drift_x_px", x, "px")
            h.measure(cam, "drift_y_px", y, "px")
            h.measure(cam, "drift_x_mm", x * MM_PER_PX, "mm")
            h.measure(cam, "drift_y_mm", y * MM_PER_PX, "mm")
            h.measure(cam, "drift_sd_px", abs(rng.normal(0.03, 0.005)), "px")
            h.measure(cam, "markers_missing", 1 if (cam, day) == ("cam2", MISSING_MARKER_DAY) else 0)
            h.measure(cam, "stray_blobs", 1 if (cam, day) == ("cam1", STRAY_BLOB_DAY) else 0)
            h.measure(cam, "led_off_visible", 4 if (cam, day) == ("cam1", LED_FAIL_DAY) else 0)
            if procedure == "daily":
                h.measure(cam, "clock_offset_s", float(rng.normal(0, 0.3)), "s")
                h.measure(cam, "params_changed", 0)
            for i in range(1, 5):
                h.measure(f"{cam}/W{i}", "drift_x_px", x + rng.normal(0, 0.02), "px")
                h.measure(f"{cam}/W{i}", "drift_y_px", y + rng.normal(0, 0.02), "px")
        h.finish(finished=t + 90)

    # another rig's run, far off: a report for rig "vts" must not see it
    h = store.begin_run("drift", rig="bench", started=T0 + 20 * DAY)
    h.measure("cam1", "drift_x_px", 9.0)
    h.measure("cam1", "drift_y_px", 9.0)
    h.finish(finished=T0 + 20 * DAY + 60)


@pytest.fixture(scope="module", params=["sqlite", "postgresql"])
def store(request, tmp_path_factory):
    """The store filled by populate(), on each back end: the numbers tests run on both."""
    if request.param == "sqlite":
        url, server, name = f"sqlite:///{tmp_path_factory.mktemp('store') / 'results.sqlite'}", None, None
    else:
        server = request.getfixturevalue("pg_server")
        name = server.new_database()
        url = server.url(name)
    with ResultsStore(url) as s:
        populate(s)
        yield s
    if server is not None:
        server.drop_database(name)


@pytest.fixture(scope="module")
def sqlite_store(tmp_path_factory):
    """The same on SQLite alone, for the tests of the rendering (the file, the browser)."""
    with ResultsStore(f"sqlite:///{tmp_path_factory.mktemp('store') / 'results.sqlite'}") as s:
        populate(s)
        yield s


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("report")


@pytest.fixture(scope="module")
def html_report(store, tmp_path_factory):
    out = tmp_path_factory.mktemp("report") / "drift.html"
    return build_drift_report(store, out, now=NOW, rig="vts"), out


@pytest.fixture(scope="module")
def rendered_html(sqlite_store, out_dir):
    out = out_dir / "drift.html"
    return build_drift_report(sqlite_store, out, now=NOW, rig="vts"), out


@pytest.fixture(scope="module")
def pdf_report(sqlite_store, out_dir):
    out = out_dir / "drift.pdf"
    return build_drift_report(sqlite_store, out, now=NOW, rig="vts"), out


# --- numbers ------------------------------------------------------------------------------


def test_forecast_matches_the_injected_trend(html_report):
    report, _ = html_report
    cam2 = report.cameras["cam2"]
    # fitted on the runs since the day-10 baseline only (the older runs drift faster)
    assert cam2.baseline_t == pytest.approx(BASELINE_T)
    assert cam2.axes["y"].trend.n == N_DAYS - NEW_BASELINE_DAY
    assert cam2.axes["y"].trend.slope_per_30d == pytest.approx(CAM2_Y_SLOPE * 30, abs=0.02)
    assert 0 < cam2.axes["y"].trend.slope_se_per_30d < 0.01
    f = cam2.axes["y"].forecast
    assert f.status == "date" and f.level == NEW_WINDOW.action_high  # the window in effect now
    expected = BASELINE_T + NEW_WINDOW.action_high / CAM2_Y_SLOPE * DAY
    assert abs(f.t - expected) < 3 * DAY, (f.t - expected) / DAY
    assert cam2.nearest_forecast()[0] == "y"


def test_flat_camera_has_no_forecast(html_report):
    report, _ = html_report
    for axis in ("x", "y"):
        tr = report.cameras["cam1"].axes[axis].trend
        f = report.cameras["cam1"].axes[axis].forecast
        # a slope of noise: no date, and the reason says so
        assert tr.ok and not tr.significant and tr.p_value >= 0.05
        assert f.status == "not significant" and f.t is None and not f.within_year
        assert f.label(str) == "none: trend not significant" and "not significant (p = " in f.reason
    # cam2 x drifts, significantly but slowly: reaches 1.5 px after about 500 days
    x = report.cameras["cam2"].axes["x"]
    assert x.trend.significant and x.forecast.status == "beyond horizon"
    assert x.forecast.label(str) == "not within a year"
    assert report.cameras["cam1"].nearest_forecast() is None


def test_bands_follow_the_window_change(html_report):
    report, _ = html_report
    for axis in ("x", "y"):
        segs = report.bands[axis]
        assert [s.window for s in segs] == [OLD_WINDOW, NEW_WINDOW]
        assert abs(segs[1].start - WINDOW_CHANGE_T) <= 60  # found by bisection
        assert segs[0].end == segs[1].start and segs[1].end == NOW
    # the QA judged each run with the window of its day
    cam2 = report.cameras["cam2"]
    late = [p for p in cam2.points if p.t > WINDOW_CHANGE_T and p.values["drift_y_px"] > 0.85]
    assert late and all(p.status["drift_y_px"] == "TOLERANCE" for p in late)


def test_control_limits_from_the_first_runs_after_the_baseline(html_report):
    report, _ = html_report
    c = report.cameras["cam1"].axes["x"].control
    assert c.n == 10 and not c.pending
    assert c.start > BASELINE_T and c.end < BASELINE_T + 11 * DAY
    assert c.upper - c.mean == pytest.approx(3 * c.sd) and 0.01 < c.sd < 0.06
    assert "first 10" in report.control_method


def test_checks_aborted_runs_and_baselines(html_report):
    report, _ = html_report
    led = report.cameras["cam1"].events("led_off_visible")
    assert [int((p.t - T0) // DAY) for p in led] == [LED_FAIL_DAY]
    assert led[0].status["led_off_visible"] == "ACTION"
    assert [int((p.t - T0) // DAY) for p in report.cameras["cam2"].events("markers_missing")] == [MISSING_MARKER_DAY]
    assert [r.status for r in report.not_completed] == ["aborted"]
    assert "503" in report.not_completed[0].notes
    assert len(report.baselines) == 2 and report.cameras["cam2"].baselines == [r.started for r in report.baselines]
    # the other rig's run is not in this report
    assert all(abs(p.values["drift_x_px"]) < 3 for c in report.cameras.values() for p in c.points)
    assert len(report.cameras["cam1"].points) == N_DAYS
    assert sorted(report.cameras["cam1"].markers) == ["W1", "W2", "W3", "W4"]
    assert report.cameras["cam1"].mm_per_px["x"] == pytest.approx(MM_PER_PX)


def test_results_data_is_json(html_report):
    report, _ = html_report
    data = json.loads(json.dumps(report.results_data(), allow_nan=False))
    assert set(data["cameras"]) == {"cam1", "cam2"}
    y = data["cameras"]["cam2"]["axes"]["y"]
    assert y["forecast"]["status"] == "date" and y["trend"]["significant"] is True
    assert len(data["cameras"]["cam2"]["series"]) == N_DAYS
    assert len(data["bands"]["y"]) == 2 and data["not_completed"][0]["status"] == "aborted"


def test_since_limits_the_period_but_not_the_fit(store, tmp_path):
    since = parse_since("30d", now=NOW)
    report = collect(store, since=since, now=NOW, rig="vts")
    cam2 = report.cameras["cam2"]
    assert all(p.t >= since for p in cam2.points) and len(cam2.points) in (30, 31)
    assert cam2.axes["y"].trend.n == N_DAYS - NEW_BASELINE_DAY  # still from the baseline on
    assert report.baselines == [] and report.period_start == since
    assert len(report.bands["y"]) == 2  # the change is within 30 days


def test_empty_store_and_bad_suffix(tmp_path):
    with ResultsStore(f"sqlite:///{tmp_path / 'empty.sqlite'}") as s:
        report = build_drift_report(s, tmp_path / "empty.html", now=NOW)
        assert report.cameras == {} and report.plot_count == 0
        assert "No completed drift runs" in (tmp_path / "empty.html").read_text()
        assert build_drift_report(s, tmp_path / "empty.pdf", now=NOW).cameras == {}
        assert (tmp_path / "empty.pdf").read_bytes().startswith(b"%PDF")
        with pytest.raises(ReportError, match=r"\.html or \.pdf"):
            build_drift_report(s, tmp_path / "r.txt")


def test_parse_since():
    now = 1_790_000_000.0
    assert parse_since("60d", now=now) == now - 60 * DAY
    assert parse_since("8w", now=now) == now - 56 * DAY
    assert parse_since("12h", now=now) == now - 12 * 3600
    assert parse_since("2026-09-01") == dt.datetime(2026, 9, 1, tzinfo=dt.UTC).timestamp()
    assert parse_since("2026-09-01T08:30+02:00") == dt.datetime(2026, 9, 1, 6, 30, tzinfo=dt.UTC).timestamp()
    assert parse_since("all", now=now) is None and parse_since(" ALL ") is None
    for bad in ("", "sixty days", "60x", "2026-13-01", "-5d", "1e400d", "nan", "2026-02-30"):
        with pytest.raises(BadSince, match="expected a duration"):
            parse_since(bad, now=now)
    for absurd in ("1000000d", "99999999999w", "9" * 400 + "d"):
        with pytest.raises(BadSince, match=r"reaches back before 1970-01-01.*give at most 20717d"):
            parse_since(absurd, now=now)
    with pytest.raises(BadSince, match=r"is before 1970-01-01"):
        parse_since("0001-01-01", now=now)
    with pytest.raises(BadSince, match=r"'9999-12-31' is in the future"):
        parse_since("9999-12-31", now=now)
    assert issubclass(BadSince, ValueError) and BadSince("x").exit_code == 2


def test_trend_functions():
    t = T0 + np.arange(20) * DAY
    tr = fit_trend(t, 0.1 + 0.05 * np.arange(20))
    assert tr.slope_per_day == pytest.approx(0.05) and tr.slope_se_per_day == pytest.approx(0, abs=1e-12)
    assert tr.significant and tr.span_days == 19
    f = forecast(tr, -2.0, 2.0, now=t[-1])
    assert f.status == "date" and f.t == pytest.approx(T0 + (2.0 - 0.1) / 0.05 * DAY)
    assert forecast(tr, -2.0, None, now=t[-1]).status == "no limit"
    assert forecast(tr, -2.0, 0.5, now=t[-1]).status == "reached"
    down = fit_trend(t, -0.001 * np.arange(20))
    assert forecast(down, -2.0, 2.0, now=t[-1]).status == "beyond horizon"
    assert not fit_trend(t[:2], [0, 1]).ok and forecast(fit_trend(t[:2], [0, 1]), -1, 1, t[-1]).status == "no fit"
    assert control_limits(t[:5], np.zeros(5)).pending


def test_a_trend_needs_five_runs_over_seven_days():
    rng = np.random.default_rng(3)
    # three runs minutes apart: their noise over minutes would be hundreds of px per 30 days
    minutes = T0 + np.array([0, 240, 480])
    tr = fit_trend(minutes, [0.004, -0.003, 0.006])
    assert not tr.ok and tr.slope_per_30d is None
    assert tr.reason == "3 runs over 0.0 days: a trend needs 5 runs over 7 days"
    f = forecast(tr, -2.0, 2.0, now=minutes[-1])
    assert f.status == "no fit" and f.t is None and f.reason == tr.reason
    # enough runs but too short a span; enough span but too few runs
    assert fit_trend(T0 + np.arange(10) * 0.5 * DAY, np.zeros(10)).reason.startswith("10 runs over 4.5 days")
    assert fit_trend(T0 + np.array([0, 5, 10, 20]) * DAY, np.arange(4.0)).reason.startswith("4 runs over 20.0 days")
    # exactly five over seven days: a trend, with SE, 95 % CI (t with 3 dof) and p-value
    t = T0 + np.linspace(0, 7, 5) * DAY
    tr = fit_trend(t, 0.05 * np.linspace(0, 7, 5) + rng.normal(0, 0.01, 5))
    assert tr.ok and tr.n == 5 and tr.span_days == pytest.approx(7)
    assert tr.ci95_per_day == pytest.approx(3.182 * tr.slope_se_per_day, rel=1e-3)
    assert tr.significant and tr.p_value < 0.001


def test_no_forecast_without_a_significant_slope():
    rng = np.random.default_rng(11)
    t = T0 + np.arange(12) * DAY
    v = rng.normal(0, 0.2, 12)  # a camera that does not move, measured noisily
    tr = fit_trend(t, v)
    assert tr.ok and not tr.significant
    f = forecast(tr, -2.0, 2.0, now=t[-1])
    assert f.status == "not significant" and f.t is None and f"p = {tr.p_value:.2f}" in f.reason
    # the same slope with little noise is significant, and gets its date
    sure = fit_trend(t, tr.slope_per_day * np.arange(12) + rng.normal(0, 0.001, 12))
    assert sure.significant
    assert forecast(sure, -2.0, 2.0, now=t[-1]).status in ("date", "beyond horizon")


# --- files --------------------------------------------------------------------------------


def _pdf_pages(path: Path) -> int:
    if shutil.which("pdfinfo"):
        out = subprocess.run(["pdfinfo", str(path)], capture_output=True, text=True, check=True).stdout
        return int(re.search(r"^Pages:\s+(\d+)", out, re.M).group(1))
    data = path.read_bytes()
    counts = re.findall(rb"/Type\s*/Pages\b[^>]*?/Count\s+(\d+)", data, re.S)
    counts += re.findall(rb"/Count\s+(\d+)[^>]*?/Type\s*/Pages\b", data, re.S)
    assert counts, "no /Pages /Count in the PDF"
    return max(int(c) for c in counts)


def test_pdf_is_valid_with_a_page_per_camera(pdf_report):
    report, out = pdf_report
    data = out.read_bytes()
    assert data.startswith(b"%PDF-") and data.rstrip().endswith(b"%%EOF")
    assert _pdf_pages(out) == 1 + len(report.cameras) == 3


def test_html_is_self_contained(rendered_html):
    report, out = rendered_html
    html = out.read_text(encoding="utf-8")
    refs = re.findall(r"""(?:src|href|action|poster)\s*=\s*["']?([^"'\s>]+)""", html, re.I)
    assert refs and all(r.startswith(("data:", "#")) for r in refs), [
        r for r in refs if not r.startswith(("data:", "#"))
    ]
    assert not re.search(r"https?://|//[a-z0-9.-]+\.[a-z]{2,}/|@import|<link\b|url\(", html, re.I)
    assert html.count('<img class="plot"') == report.plot_count == 2
    for text in ("not within a year", "aborted", "control limits", "cam1", "cam2", "LED check failed"):
        assert text.lower() in html.lower(), text


# --- in a real browser --------------------------------------------------------------------


def _chromium() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    assert exe, CHROMIUM_HELP
    return exe


def _run_chromium(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    profile = tmp_path / "chromium-profile"
    cmd = [
        _chromium(),
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-dev-shm-usage",
        "--hide-scrollbars",
        f"--user-data-dir={profile}",
        *args,
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=90)


def test_html_renders_in_chromium(rendered_html, tmp_path):
    report, out = rendered_html
    r = _run_chromium(tmp_path, "--virtual-time-budget=5000", "--dump-dom", out.resolve().as_uri())
    assert r.returncode == 0, r.stderr[-2000:]
    m = re.search(r'<body[^>]*data-plots-loaded="(\d+)"', r.stdout)
    assert m, "the report's script did not run in the browser:\n" + r.stdout[:500] + r.stderr[-1000:]
    assert int(m.group(1)) == report.plot_count == 2
    assert f'data-plots-expected="{report.plot_count}"' in r.stdout


def test_html_screenshot_is_not_blank(rendered_html, tmp_path):
    from PIL import Image

    _, out = rendered_html
    shot = tmp_path / "report.png"
    r = _run_chromium(
        tmp_path,
        "--window-size=1280,2400",
        "--virtual-time-budget=5000",
        f"--screenshot={shot}",
        out.resolve().as_uri(),
    )
    assert r.returncode == 0 and shot.exists(), r.stderr[-2000:]
    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert img.shape[0] >= 2000 and img.shape[1] >= 1200
    dark = (img.sum(axis=2) < 300).mean()
    assert 0.005 < dark < 0.5, dark  # text and plot lines, not a blank page
    red = ((img[..., 0] > 170) & (img[..., 1] < 90) & (img[..., 2] < 90)).sum()
    green = ((img[..., 1] > 100) & (img[..., 0] < 80) & (img[..., 2] < 80)).sum()
    assert red > 200 and green > 200, (red, green)  # the state colours are drawn
    if dest := os.environ.get("VTS_REPORT_SCREENSHOT"):
        shutil.copy(shot, dest)
