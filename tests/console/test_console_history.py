"""The console's History page (issue 23 §1): the runs of the results store, a run's figures and
files, the drift report and the rooms page, read-only.

The store is filled by the one recorder (tests/history_store.py); the routes are served by
Starlette's TestClient (in process, no socket): filters and their URL, paging newest first, a bad
filter is one sentence and HTTP 400, a run's page with its tolerance windows and plot, only the
files the store lists for that run are served (by id; a `../` or another run's file is 404), a
deleted file says so, the reports are rendered from the store into a temporary folder and
nothing is written into the working folder. One test in Debian's Chromium (Playwright) clicks
through it as a user does, against `vts console` served as users run it.
"""

from __future__ import annotations

import datetime as dt
import os
from pathlib import Path

import pytest
from starlette.testclient import TestClient

from history_store import N_DAILY, RIG, fill
from vts_hw import catalog
from vts_hw.console.app import Console, create_app
from vts_hw.console.history import PAGE_SIZE
from vts_hw.store import ResultsStore

pytestmark = pytest.mark.timeout(120)
N_RUNS = 1 + N_DAILY + 1 + 1 + 1 + 1 + 1 + 1  # baseline, daily, sync, motion, aborted, running, other rig, error


@pytest.fixture(scope="module")
def filled(tmp_path_factory):
    folder = tmp_path_factory.mktemp("history")
    db = folder / "results.sqlite"
    ids = fill(db, folder)
    return db, ids


@pytest.fixture()
def client(filled, tmp_path, monkeypatch):
    db, _ = filled
    monkeypatch.chdir(tmp_path)  # the console must write nothing here
    console = Console(RIG, None, None, None, open_store=lambda: ResultsStore(db, mode="read"))
    with TestClient(create_app(console), base_url="http://127.0.0.1:8040") as c:
        yield c
    assert list(tmp_path.iterdir()) == []


def rows(html: str) -> list[int]:
    """The run ids listed, in the page's order."""
    import re

    return [int(m) for m in re.findall(r'<tr data-run="(\d+)"', html)]


def test_store_pages_runs_newest_first_and_gives_the_windows(filled):
    db, ids = filled
    with ResultsStore(db, mode="read") as store:
        page, total = store.runs_page(limit=10)
        assert total == N_RUNS and len(page) == 10
        assert [r.started for r in page] == sorted((r.started for r in page), reverse=True)
        assert page[0].id == ids["running"]
        second, _ = store.runs_page(limit=10, offset=10)
        assert not {r.id for r in page} & {r.id for r in second}
        daily, n = store.runs_page(procedure=("daily", "drift"), status="ACTION")
        assert n == 3 and {r.id for r in daily} == set(ids["daily"][-3:])
        t = daily[0].started
        one, n = store.runs_page(procedure="daily", start=t - 1, end=t + 1)
        assert n == 1 and one[0].id == daily[0].id
        ms = store.measurements(run_id=ids["daily"][-1])
        windows = store.windows(m.tolerance_id for m in ms)
        assert windows and all(m.tolerance_id in windows for m in ms if m.metric == "drift_y_px")
        assert windows[ms[0].tolerance_id].unit == "px"
        assert store.windows([]) == {} and store.windows([None]) == {}


def test_the_history_queries_compile_for_postgresql():
    from sqlalchemy.dialects import postgresql

    from vts_hw.store import queries

    pg = postgresql.dialect()
    lit = {"literal_binds": True}
    sql = str(
        queries.select_runs_newest(("daily", "drift"), "ACTION", 10.0, 20.0, 50, 100).compile(
            dialect=pg, compile_kwargs=lit
        )
    )
    assert "runs.procedure IN ('daily', 'drift')" in sql and "runs.status = 'ACTION'" in sql
    assert "runs.started >= 10.0" in sql and "runs.started < 20.0" in sql
    assert "ORDER BY runs.started DESC, runs.id DESC" in sql and "LIMIT 50 OFFSET 100" in sql
    sql = str(queries.count_runs("sync", None, None, 5.0).compile(dialect=pg, compile_kwargs=lit))
    assert sql.startswith("SELECT count(*)") and "runs.started < 5.0" in sql and "ORDER BY" not in sql
    sql = str(queries.select_tolerances_by_id([3, 1]).compile(dialect=pg, compile_kwargs=lit))
    assert "tolerances.id IN (3, 1)" in sql


def test_catalog_labels_group_the_stored_names():
    labels = catalog.by_label()
    assert set(labels["daily QA"]) == {catalog.DAILY.name, catalog.DRIFT.name}
    assert labels["camera calibration"] == catalog.CALIBRATION.stored_as
    assert sum(len(v) for v in labels.values()) == len(catalog.by_name())


def test_history_lists_newest_first_in_pages(client, filled):
    _, ids = filled
    r = client.get("/history")
    assert r.status_code == 200
    first = rows(r.text)
    assert len(first) == PAGE_SIZE and first[0] == ids["running"]
    assert f"of {N_RUNS}, newest first" in r.text and 'href="/history?page=2"' in r.text
    second = rows(client.get("/history?page=2").text)
    assert len(second) == N_RUNS - PAGE_SIZE and not set(first) & set(second)
    assert second[-1] == ids["baseline"]
    # states in colour and words; procedures by label, never the stored name
    assert '<span class="st st-running">running</span>' in r.text
    assert '<span class="st st-aborted">aborted</span>' in r.text and '<span class="st st-error">error</span>' in r.text
    assert '<td class="procedure">daily QA</td>' in r.text and '<td class="procedure">daily</td>' not in r.text
    assert '<a href="/" >' not in r.text and 'href="/history" class="here"' in r.text
    assert client.get("/history?page=9").status_code == 200 and rows(client.get("/history?page=9").text) == []


def test_history_filters_by_procedure_state_and_dates(client, filled):
    _, ids = filled
    r = client.get("/history", params={"procedure": "daily QA", "state": "ACTION"})
    assert r.status_code == 200 and rows(r.text) == list(reversed(ids["daily"][-3:]))
    assert '<option value="daily QA" selected>' in r.text and '<option value="ACTION" selected>' in r.text
    assert rows(client.get("/history?procedure=daily+QA&state=TOLERANCE").text) == list(reversed(ids["daily"][-7:-3]))
    assert rows(client.get("/history?procedure=sync+check").text) == [ids["running"], ids["sync"], ids["error"]]
    assert rows(client.get("/history?state=aborted").text) == [ids["aborted"]]
    with ResultsStore(filled[0], mode="read") as store:
        day = dt.datetime.fromtimestamp(store.run(ids["motion"]).started, dt.UTC).date().isoformat()
        in_day = sorted(
            (r.id for r in store.runs() if dt.datetime.fromtimestamp(r.started, dt.UTC).date().isoformat() == day),
            reverse=True,
        )
    got = rows(client.get(f"/history?from={day}&to={day}").text)
    assert ids["motion"] in got and sorted(got, reverse=True) == in_day
    assert rows(client.get(f"/history?procedure=motion+analysis&from={day}").text) == [ids["motion"]]
    empty = client.get("/history?procedure=SPECT+mapping")
    assert empty.status_code == 200 and rows(empty.text) == [] and "no runs match" in empty.text


@pytest.mark.parametrize(
    "query, says",
    [
        ("procedure=daily", "no procedure called 'daily'"),
        ("procedure=nonsense", "no procedure called 'nonsense'"),
        ("state=FINE", "no run state 'FINE'"),
        ("from=yesterday", "the from date 'yesterday' is not a date"),
        ("to=2026-02-30", "the to date '2026-02-30' is not a date"),
        ("from=2026-03-02&to=2026-03-01", "the from date 2026-03-02 is after the to date 2026-03-01"),
        ("page=0", "page '0' is not a page number"),
        ("page=two", "page 'two' is not a page number"),
    ],
)
def test_a_bad_filter_is_one_sentence_and_400(client, query, says):
    r = client.get(f"/history?{query}")
    assert r.status_code == 400
    import html

    assert says in html.unescape(r.text) and "Traceback" not in r.text and rows(r.text) == []
    assert r.text.count('class="error message"') == 1
    assert '<form class="filters"' in r.text  # the form stays, to be put right


def test_a_run_page_shows_its_figures_windows_and_files(client, filled):
    _, ids = filled
    r = client.get(f"/history/run/{ids['sync']}")
    assert r.status_code == 200
    t = r.text
    assert f"Run {ids['sync']:d}: sync check" in t and "physicist" in t and "after the gantry service" in t
    assert "room-h" in t and "vts-hw " in t and " UTC" in t
    assert '<tr data-metric="sync_max_abs_dt_ms">' in t and '<td class="num">12</td>' in t
    assert "OK ≤ 20, ACTION above 100 ms" in t  # the window that judged it, in words
    assert "none stored: judged by its procedure" in t  # sync_offset_ms has no window
    assert f'class="plot" src="/history/run/{ids["sync"]:d}/file/' in t
    assert "sync.csv</a>" in t and "gone.csv: file no longer there" in t
    daily = client.get(f"/history/run/{ids['daily'][-1]}").text
    assert '<span class="st st-ACTION">ACTION</span>' in daily and "daily QA" in daily
    aborted = client.get(f"/history/run/{ids['aborted']}").text
    assert "the phantom slipped" in aborted and "No measures stored" in aborted
    missing = client.get("/history/run/999999")
    assert missing.status_code == 404 and "there is no run 999999" in missing.text


def _artifact_ids(client, run_id) -> list[int]:
    import re

    return [int(a) for a in re.findall(r'<li data-artifact="(\d+)"', client.get(f"/history/run/{run_id}").text)]


def test_only_the_runs_own_listed_files_are_served(client, filled):
    _, ids = filled
    files = ids["files"]
    png_id, csv_id, gone_id = _artifact_ids(client, ids["sync"])
    r = client.get(f"/history/run/{ids['sync']}/file/{png_id}")
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert r.content == files["png"].read_bytes()
    r = client.get(f"/history/run/{ids['sync']}/file/{csv_id}")
    assert r.status_code == 200 and r.content == files["csv"].read_bytes()
    assert "attachment" in r.headers["content-disposition"] and r.headers["x-content-type-options"] == "nosniff"
    gone = client.get(f"/history/run/{ids['sync']}/file/{gone_id}")
    assert gone.status_code == 404 and gone.text.startswith("file no longer there: gone.csv")
    other = client.get(f"/history/run/{ids['motion']}/file/{png_id}")  # another run's file
    assert other.status_code == 404 and "has no file" in other.text
    secret = Path(files["png"]).parent / "results.sqlite"
    for url in (
        f"/history/run/{ids['sync']}/file/../../../../etc/passwd",
        f"/history/run/{ids['sync']}/file/..%2F..%2Fetc%2Fpasswd",
        f"/history/run/{ids['sync']}/file/{secret}",
        f"/history/run/{ids['sync']}/file/sync.png",
        f"/history/run/{ids['sync']}/file/-1",
    ):
        r = client.get(url)
        assert r.status_code == 404, url
        assert b"root:" not in r.content and b"SQLite format" not in r.content


def test_the_reports_are_rendered_from_the_store_into_a_temporary_folder(client, filled, tmp_path_factory, monkeypatch):
    import tempfile

    # a temporary folder of this test's own: another worker's console renders its rooms into /tmp too
    private = tmp_path_factory.mktemp("own-tmp")
    monkeypatch.setattr(tempfile, "tempdir", str(private))
    before = set(os.listdir(tempfile.gettempdir()))
    r = client.get("/history/drift-report")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert RIG in r.text and "cam1" in r.text and "data:image/png;base64," in r.text
    assert "room-z" not in r.text  # the console's rig only
    rooms = client.get("/history/rooms/")
    assert rooms.status_code == 200 and RIG in rooms.text and "room-z" in rooms.text
    import re

    links = re.findall(r'href="(rooms-[^"]+\.html)"', rooms.text)
    assert links, rooms.text[:2000]
    linked = client.get(f"/history/rooms/{links[0]}")
    assert linked.status_code == 200 and "cam" in linked.text
    assert client.get("/history/rooms/results.sqlite").status_code == 404
    assert client.get("/history/rooms/..%2F..%2Fetc%2Fpasswd").status_code == 404
    bad = client.get("/history/drift-report?since=soon")
    assert bad.status_code == 400 and "soon" in bad.text and "Traceback" not in bad.text
    # the drift report's folder is gone; the rooms page's is kept (its links) until the next one
    left = {n for n in set(os.listdir(tempfile.gettempdir())) - before if n.startswith("vts-console-")}
    assert all(n.startswith("vts-console-rooms-") for n in left) and len(left) <= 1


def test_a_store_that_cannot_be_read_is_said_so(tmp_path):
    def broken():
        return ResultsStore(tmp_path / "no-such-folder" / "results.sqlite", mode="read")

    console = Console(RIG, None, None, None, open_store=broken)
    with TestClient(create_app(console), base_url="http://127.0.0.1:8040") as c:
        r = c.get("/history")
        assert r.status_code == 503 and "the results store could not be read" in r.text and "Traceback" not in r.text
        assert c.get("/history/run/1").status_code == 503
        d = c.get("/history/drift-report")
        assert d.status_code == 503 and "the report could not be made" in d.text


# -- in a real browser ---------------------------------------------------------------------------------


def test_history_in_chromium(filled, tmp_path):
    """`vts console` as users run it, its store the filled one; Chromium opens the Room page,
    follows History, filters by a procedure and a state (the URL says so), opens a run and sees
    its plot loaded and its measures."""
    from console_live import chromium, start_console, stop_console, wait_js
    from vts_hw.sim_devices.rig import SimRig

    db, ids = filled
    with SimRig(n_cameras=1, seed=3) as rig, rig.env():
        rig_yaml, _ = rig.write(tmp_path)
        env = {**os.environ, **rig.env_vars(), "VTS_CONFIG": str(rig_yaml), "VTS_STORE": str(db)}
        p, url = start_console(["--port", "0"], env)
        try:
            with chromium() as b:
                pg = b.new_page(viewport={"width": 1366, "height": 768})
                pg.goto(url)
                pg.click("header nav a[href='/history']")
                pg.wait_for_url("**/history")
                assert pg.locator("table.runs tbody tr").count() == PAGE_SIZE
                pg.select_option("select[name=procedure]", "sync check")
                pg.select_option("select[name=state]", "OK")
                pg.click("form.filters button[type=submit]")
                pg.wait_for_url("**/history?procedure=sync+check&state=OK**")
                assert pg.locator("table.runs tbody tr").count() == 1
                assert pg.inner_text("table.runs tbody tr .st") == "OK"
                pg.click(f'tr[data-run="{ids["sync"]}"] td a >> nth=0')
                pg.wait_for_url(f"**/history/run/{ids['sync']}")
                wait_js(
                    pg,
                    "() => { const i = document.querySelector('img.plot');"
                    " return i && i.complete && i.naturalWidth > 0; }",
                    timeout=15000,
                )
                assert pg.eval_on_selector("img.plot", "i => i.naturalWidth") == 240
                assert "12" in pg.inner_text('tr[data-metric="sync_max_abs_dt_ms"] td.num')
                color = pg.eval_on_selector("#run-state", "e => getComputedStyle(e).backgroundColor")
                assert pg.inner_text("#run-state") == "OK" and color == "rgb(220, 252, 231)"
        finally:
            code, out, err = stop_console(p)
            assert code == 0 and "Traceback" not in err, (code, out, err)


def test_the_qa_pages_drift_plot_is_drawn_through_the_report_packages_name(filled):
    """The QA page's drift plot (qa_view.drift_plot_png) takes the plot through the report
    package's name loaded when first asked for (the console starts without matplotlib): drawn, a PNG."""
    from vts_hw.console.qa_view import drift_plot_png

    db, _ = filled
    png = drift_plot_png(lambda: ResultsStore(db, mode="read"), RIG, "cam1")
    assert png is not None and png.startswith(b"\x89PNG\r\n\x1a\n") and len(png) > 10_000
    assert drift_plot_png(lambda: ResultsStore(db, mode="read"), RIG, "no-such-camera") is None
