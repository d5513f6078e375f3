"""Every `vts` command swept with bad paths, numbers, configs, non-finite floats, databases that
are not a results store, and (every command that writes) a full disk (bench/bad_inputs.py): no
traceback, no hang, no false OK, no data damaged, only documented exit codes."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.timeout(900)
def test_every_command_answers_bad_input_in_one_sentence():
    p = subprocess.run([sys.executable, str(REPO / "bench" / "bad_inputs.py"), "--json", "--timeout", "120"],
                       capture_output=True, text=True, timeout=900)
    r = json.loads(p.stdout)
    print(f"{r['cases']} bad inputs, {r['passed']} passed")
    for cls, c in r["classes"].items():
        print(f"  {cls}: {c}")
    assert r["cases"] >= 700                      # every command was swept
    per = r["classes"]
    assert set(per) == {"paths", "numbers", "floats", "configs", "foreign stores", "full disk"}
    for cls, c in per.items():
        assert c["cases"] > 0, cls
        assert (c["tracebacks"], c["hangs"], c["false_oks"], c["damaged"], c["other"]) == (0, 0, 0, 0, 0), \
            (cls, c, r["failures"][:10])
    assert per["floats"]["cases"] >= 14 * 5       # every float option, nan/inf/-inf/1e309/NaN at least
    assert per["full disk"]["cases"] >= 19        # every writing command on a real full disk (CI runs as root)
    # the store was reached, and refused, by the commands that open one
    assert per["foreign stores"]["opened"] >= 30
    for cmd in ("store info", "store migrate", "store init", "report drift", "report rooms", "qa daily",
                "qa push", "qa import", "calibrate stereo"):
        assert cmd in r["opened_by"], (cmd, r["opened_by"])
    assert r["failures"] == [] and r["passed"] == r["cases"] and p.returncode == 0
