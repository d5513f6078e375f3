"""The Scan page's screenshot (docs/console/scan.png) at 1366 x 768, in Debian's Chromium.

    .venv/bin/python tools/scan_screenshot.py [OUT.png]

A simulated rig of two cameras with a breathing patient (frames made ahead), `vts console
--scans-dir TMP` as users run it (tools/console_screenshots.py's stage has neither), a scan
started from the page; photographed while it runs, after the patient moved once (the banner up,
not yet acknowledged) with about 20 s of breathing traced. Run by hand when the page changes;
no test writes into docs/.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

SCAN_S = 40.0
MOVE_AT_S = 20.0
SHOOT_AT_S = 26.0


def main(out: Path) -> None:
    from console_live import chromium, start_console, stop_console, until
    from vts_hw.sim_devices.patient import BodyMove, add_patient
    from vts_hw.sim_devices.rig import SimRig

    with tempfile.TemporaryDirectory(prefix="vts-scan-shot-") as tmp, SimRig(n_cameras=2, seed=3) as rig, rig.env():
        tmp = Path(tmp)
        rig.ntp_sync()
        rig_yaml, _ = rig.write(tmp / "rig")
        patient = add_patient(rig.scene, time.time(), 600.0, seed=5, moves=[])
        env = {
            **os.environ,
            **rig.env_vars(),
            "VTS_CONFIG": str(rig_yaml),
            "VTS_STORE": f"sqlite:///{tmp / 'results.sqlite'}",
        }
        p, url = start_console(["--port", "0", "--scans-dir", str(tmp / "scans")], env)
        try:
            with chromium() as b:
                pg = b.new_page(viewport={"width": 1366, "height": 768})
                pg.goto(url + "scan")
                now = rig.clock.now()
                patient.motion.moves.append(
                    BodyMove(now + MOVE_AT_S, now + MOVE_AT_S + 0.6, (0.0, 1.0, 0.0), (2.0, 5.0, 2.0))
                )
                rig.prerender(SCAN_S + 5.0)
                pg.fill("#reference", "5")
                pg.fill("#duration", f"{SCAN_S:g}")
                pg.click("#start")
                until(lambda: pg.get_attribute("#scan", "data-phase") == "running", 60)
                t0 = time.monotonic()
                until(lambda: time.monotonic() - t0 > SHOOT_AT_S and pg.query_selector(".alert"), SCAN_S)
                pg.screenshot(path=str(out))
                pg.click("#stop")
                until(lambda: pg.get_attribute("#scan", "data-phase") == "stopped", 60)
        finally:
            stop_console(p)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "console" / "scan.png")
