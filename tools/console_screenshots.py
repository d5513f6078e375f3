"""Screenshots of the console's pages at 1366 x 768 in Debian's Chromium, into docs/console/.

    .venv/bin/python tools/console_screenshots.py [--out DIR] [--only FILE ...]

One stage for every page: two simulated Axis cameras on 127.0.0.1 (their LED rings on, each
camera's drift baseline in the store so its wall markers are named) and the QATrack+ stand-in,
a temporary results store filled as tests/history_store.py fills it (the History page's runs),
and the console's app served in this process (tests/console_live.py: the objects `vts console`
builds, on the rig.yaml the Daily QA page runs on). Then each row of ``SHOTS`` is
photographed: its page (a path, or a function of the stage giving it), once the page says it
is ready (a JavaScript expression), after its own setup (before the page is opened) and
actions on the page (after) if it has them.

A new page adds a row: ``Shot(path, file, ready=..., setup=..., act=...)``. The Scan page is
photographed by tools/scan_screenshot.py: it needs a rig of its own (a breathing patient, its
frames made ahead, `vts console --scans-dir`). Run by hand when a page changes; no test writes
into docs/.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]


@dataclass
class Stage:
    """What the pages are shown on: the simulated rig, the console in this process, the store's ids."""

    rig: object
    live: object
    ids: dict
    folder: Path | None = None  # a temporary folder of the stage's own


@dataclass(frozen=True)
class Shot:
    path: str | Callable[[Stage], str]  # the page, from the console's root
    file: str  # in the output folder
    ready: str = "true"  # a JS expression: true once the page shows what it should
    setup: Callable[[Stage], None] | None = None  # done before the page is opened
    act: Callable[[Stage, object], None] | None = None  # done on the page (a Playwright Page), once opened


ROOM_READY = (
    "[...document.querySelectorAll('section.camera')].every(s => s.dataset.live === 'yes'"
    " && s.querySelectorAll('svg circle').length >= 3 && s.dataset.led === 'on'"
    " && s.querySelector('.offset').textContent.includes('ms'))"
)

AIM_READY = (
    "[...document.querySelectorAll('section.camera')].every(s => ['good', 'adjust'].includes(s.dataset.aim)"
    " && s.querySelector('img.aim-picture').naturalWidth > 0"
    " && s.querySelector('img.aim-picture').dataset.check === s.dataset.aimCheck)"
)


def aim_on(st: Stage) -> None:
    """The Room page's aim & focus on both cameras, with the rig's true calibration and mapping (the
    FOV, table and gantry drawn) and cam2's lens put out of focus (an ADJUST to show)."""
    from vts_hw.sim_devices.sync_truth import write_true_calibration

    cal, mp = write_true_calibration(st.rig.scene, st.folder)
    st.live.console.rig_config = st.rig.config(calibration={"stereo": str(cal), "spect": str(mp)})
    st.rig.sources["cam2"].set_optics(focus_blur_px=1.5)
    for name in st.live.console.hub.names:
        st.live.console.aim.switch(name, True, "screenshots")


QA_READY = (
    "[...document.querySelectorAll('img.drift')].length === 2 && "
    "[...document.querySelectorAll('img.drift')].every(i => i.complete && i.naturalWidth > 0)"
)


def daily_qa(st: Stage, page) -> None:
    """The Daily QA page: the daily QA run from it (on the stage's drift baselines), then pushed to
    the QATrack+ stand-in."""
    from console_live import wait_js

    said = "t => document.getElementById('said').textContent.includes(t)"
    page.fill("#frames", "3")
    page.click("#run")
    wait_js(page, said, "Daily QA done", 120_000)
    page.click("#push")
    wait_js(page, said, "QATrack+: 1 of 1", 120_000)


SHOTS: list[Shot] = [
    Shot("/", "room.png", ROOM_READY),
    Shot("/history", "history.png", "document.querySelectorAll('table.runs tbody tr').length > 0"),
    Shot(
        lambda st: f"/history/run/{st.ids['sync']}",
        "history-run.png",
        "(() => { const i = document.querySelector('img.plot'); return i && i.complete && i.naturalWidth > 0; })()",
    ),
    Shot("/qa", "daily-qa.png", QA_READY, act=daily_qa),  # after History's: its run would be listed there
    Shot("/", "room-aim.png", AIM_READY, setup=aim_on),  # last: it leaves the checks on and cam2 blurred
]


def stage(folder: Path):
    """The stage (a context manager yielding a Stage)."""
    import contextlib

    from console_live import LiveConsole, qa_rig_yaml
    from history_store import fill
    from vts_hw.config import load_rig
    from vts_hw.drivers.registry import open_camera
    from vts_hw.procedures.baseline import take_baselines
    from vts_hw.sim_devices.rig import SimRig
    from vts_hw.store import ResultsStore
    from vts_hw.store.recorder import record

    @contextlib.contextmanager
    def made():
        db = folder / "results.sqlite"
        ids = fill(db, folder)
        with SimRig(n_cameras=2, seed=5, qatrack=True) as rig, rig.env():
            cfg = load_rig(str(qa_rig_yaml(rig, folder)))  # its store: db
            cams = {c.name: open_camera(c) for c in cfg.cameras}
            try:
                with ResultsStore(db) as store:  # each camera's wall markers (the LED is left on)
                    record(store, take_baselines(list(cams.values()), frames=2), rig="sim", operator="screenshots")
                with LiveConsole(cams, cfg.rig, lambda: ResultsStore(db, mode="read"), rig_config=cfg) as live:
                    yield Stage(rig, live, ids, folder)
            finally:
                for c in cams.values():
                    c.close()

    return made()


def main(argv=None) -> int:
    from console_live import chromium, wait_js

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "console", help="where the PNGs go")
    ap.add_argument("--only", nargs="*", default=None, help="only these files (e.g. room.png)")
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds a page may take to be ready")
    a = ap.parse_args(argv)
    shots = [s for s in SHOTS if a.only is None or s.file in a.only]
    unknown = sorted(set(a.only or ()) - {s.file for s in SHOTS})
    if unknown:
        print(
            f"console_screenshots: no page makes {', '.join(unknown)} (known: {', '.join(s.file for s in SHOTS)})",
            file=sys.stderr,
        )
        return 2
    a.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="vts-console-shots-") as tmp, stage(Path(tmp)) as st, chromium() as browser:
        for shot in shots:
            if shot.setup is not None:
                shot.setup(st)
            path = shot.path(st) if callable(shot.path) else shot.path
            page = browser.new_page(viewport={"width": 1366, "height": 768})
            page.goto(st.live.url.rstrip("/") + path)
            if shot.act is not None:
                shot.act(st, page)
            wait_js(page, shot.ready, timeout=a.timeout * 1000)
            page.wait_for_timeout(500)  # the next picture and its markers drawn
            page.screenshot(path=str(a.out / shot.file))
            page.close()
            print(f"wrote {a.out / shot.file} ({path})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
