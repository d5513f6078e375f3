"""The Daily QA page's screenshot (docs/console/daily-qa.png) at 1366 x 768, in Debian's Chromium.

    .venv/bin/python tools/qa_screenshot.py [OUT.png]

Starts the simulated rig (two cameras, the QATrack+ stand-in) with a temporary results store,
serves the console in this process as tests/test_console_qa.py does, and in the page: sets a
baseline (confirmed), runs the daily QA, pushes it to QATrack+, and photographs the result with
its drift plots. Run by hand when the page changes; no test writes into docs/.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))


def main(out: Path) -> None:
    from playwright.sync_api import sync_playwright

    from tests.test_console import ARGS, CHROMIUM
    from tests.test_console_qa import InProcessConsole, _rig_yaml
    from vts_hw.config import load_rig
    from vts_hw.sim_devices.rig import SimRig
    from vts_hw.store import ResultsStore

    with tempfile.TemporaryDirectory(prefix="vts-qa-shot-") as tmp, \
            SimRig(n_cameras=2, seed=5, qatrack=True) as rig, rig.env():
        folder = Path(tmp)
        rig_yaml = _rig_yaml(rig, folder)
        ResultsStore(folder / "results.sqlite").close()
        served = InProcessConsole(load_rig(str(rig_yaml)), folder / "results.sqlite")
        try:
            with sync_playwright() as pw:
                b = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
                pg = b.new_page(viewport={"width": 1366, "height": 768})
                pg.goto(served.url + "qa")
                pg.fill("#frames", "3")
                pg.click("#baseline")
                pg.click("#confirm-yes")
                pg.wait_for_function("document.getElementById('said').textContent.includes('Baseline set')",
                                     timeout=120_000)
                pg.click("#run")
                pg.wait_for_function("document.getElementById('said').textContent.includes('Daily QA done')",
                                     timeout=120_000)
                pg.click("#push")
                pg.wait_for_function("document.getElementById('said').textContent.includes('QATrack+: 1 of 1')",
                                     timeout=120_000)
                pg.wait_for_function("[...document.querySelectorAll('img.drift')].length === 2 && "
                                     "[...document.querySelectorAll('img.drift')].every(i => i.complete && "
                                     "i.naturalWidth > 0)", timeout=120_000)
                pg.screenshot(path=str(out))
                b.close()
        finally:
            served.close()
    print(f"wrote {out}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "console" / "daily-qa.png")
