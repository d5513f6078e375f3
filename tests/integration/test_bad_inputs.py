"""Every `vts` command swept with bad paths, numbers, configs, non-finite floats, databases that
are not a results store, and (every command that writes) a full disk (bench/bad_inputs.py): no
traceback, no hang, no false OK, no data damaged, only documented exit codes.

Round 3 (issue 32 §5), each class a share meeting every command, route or action once (the whole
of each: `bench/bad_inputs.py --classes all`): every output onto a device node, FIFO, link and
folder (root writes); every long command and console job killed (what is left on disk, running,
switched on); each console action on a full disk; every console route and method as each role
and none with the web's bad inputs (web): no security finding either."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
ROUND3 = {"root writes", "killed", "console full disk", "web"}
WEB_FAMILIES = {
    "anonymous",
    "host",
    "origin",
    "token",
    "script",
    "numbers",
    "traversal",
    "bodies",
    "repeated",
    "headers",
    "many clients",
    "stop",
}


@pytest.mark.timeout(1500)
def test_every_command_answers_bad_input_in_one_sentence():
    p = subprocess.run(
        [sys.executable, str(REPO / "bench" / "bad_inputs.py"), "--json", "--timeout", "120"],
        capture_output=True,
        text=True,
        timeout=1500,
    )
    r = json.loads(p.stdout)
    print(f"{r['cases']} bad inputs, {r['passed']} passed")
    for cls, c in r["classes"].items():
        print(f"  {cls}: {c}")
    for f in r["failures"]:
        print(f"  FAILED {f}")
    assert r["cases"] >= 1000  # every command was swept
    per = r["classes"]
    assert set(per) == {"paths", "numbers", "floats", "configs", "foreign stores", "full disk"} | ROUND3
    for cls, c in per.items():
        assert c["cases"] > 0, cls
        assert (c["tracebacks"], c["hangs"], c["false_oks"], c["damaged"], c["security"], c["other"]) == (
            0,
            0,
            0,
            0,
            0,
            0,
        ), (cls, c, [f for f in r["failures"] if cls in f or cls == "web"][:10])
    assert per["floats"]["cases"] >= 14 * 5  # every float option, nan/inf/-inf/1e309/NaN at least
    assert per["full disk"]["cases"] >= 19  # every writing command on a real full disk (CI runs as root)
    # round 3: every writing command's outputs, every long command and console job, each console
    # action the issue names, every family of the web over the console's routes
    assert per["root writes"]["cases"] >= 25
    assert per["killed"]["cases"] >= 12
    assert per["console full disk"]["cases"] >= 2
    assert per["web"]["cases"] >= 200 and WEB_FAMILIES <= set(per["web"]["families"]), per["web"]
    # the store was reached, and refused, by the commands that open one
    assert per["foreign stores"]["opened"] >= 30
    for cmd in (
        "store info",
        "store migrate",
        "store init",
        "report drift",
        "report rooms",
        "qa daily",
        "qa push",
        "qa import",
        "calibrate stereo",
    ):
        assert cmd in r["opened_by"], (cmd, r["opened_by"])
    assert r["failures"] == [] and r["passed"] == r["cases"] and p.returncode == 0
