"""The History page's screenshot (docs/console/history.png) at 1366 x 768, in Debian's Chromium.

    .venv/bin/python tools/history_screenshot.py [OUT.png]

Fills a temporary results store as tests/history_store.py does (the one recorder), serves the
console's app on 127.0.0.1 (uvicorn, a free port, no cameras: the History page needs none) and
photographs /history. Run by hand when the page changes; no test writes into docs/.
"""

from __future__ import annotations

import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(out: Path) -> None:
    import uvicorn
    from playwright.sync_api import sync_playwright

    from tests.history_store import RIG, fill
    from tests.test_console import ARGS, CHROMIUM
    from vts_hw.console.app import Console, create_app
    from vts_hw.store import ResultsStore

    with tempfile.TemporaryDirectory(prefix="vts-history-shot-") as tmp:
        db = Path(tmp) / "results.sqlite"
        fill(db, Path(tmp))
        console = Console(RIG, None, None, None, open_store=lambda: ResultsStore(db, mode="read"))
        sock = socket.socket()
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
        server = uvicorn.Server(uvicorn.Config(create_app(console), log_level="warning", lifespan="off"))
        t = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
        t.start()
        while not server.started:
            time.sleep(0.05)
        try:
            with sync_playwright() as pw:
                b = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
                pg = b.new_page(viewport={"width": 1366, "height": 768})
                pg.goto(f"http://127.0.0.1:{port}/history")
                pg.screenshot(path=str(out))
                b.close()
        finally:
            server.should_exit = True
            t.join(10)
            sock.close()
    print(f"wrote {out}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "console" / "history.png")
