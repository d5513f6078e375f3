"""Every `vts` command swept with bad paths, numbers and configs (bench/bad_inputs.py): no
traceback, no hang, only documented exit codes."""

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
    print(f"{r['cases']} bad inputs, {r['passed']} answered in one sentence")
    assert r["cases"] >= 400                      # every command was swept
    assert r["tracebacks"] == [] and r["hangs"] == [] and r["bad_exit"] == []
    assert r["passed"] == r["cases"] and p.returncode == 0
