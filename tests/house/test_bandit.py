"""The package's static security check (issue 32 §5): Bandit over vts_hw/, drivers/, procedures/ and
sim_devices/ finds nothing of high or medium severity; each finding kept is justified on its line
(``# nosec BXXX: why``), and the skips in pyproject.toml's [tool.bandit] say why. The one justification
that rests on a claim about the library (expat refuses entity amplification and external entities,
drivers/discovery/ssdp.py) is checked here too."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
FOLDERS = ("vts_hw", "drivers", "procedures", "sim_devices")
NOSEC = re.compile(r"#\s*nosec\b(.*)$")
JUSTIFIED = re.compile(r"^\s*(B\d{3})(,\s*B\d{3})*:\s*\S.{8,}")


def test_bandit_finds_nothing_high_or_medium_and_every_exception_says_why():
    p = subprocess.run(
        [sys.executable, "-m", "bandit", "-c", "pyproject.toml", "-r", *FOLDERS, "-f", "json", "-q"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert p.stdout.strip(), f"bandit printed nothing (exit {p.returncode}): {p.stderr[-500:]}"
    r = json.loads(p.stdout)
    assert not r["errors"], r["errors"]
    totals = r["metrics"]["_totals"]
    print(
        f"bandit: {totals['loc']} lines, high {totals['SEVERITY.HIGH']}, medium {totals['SEVERITY.MEDIUM']}, "
        f"low {totals['SEVERITY.LOW']}, # nosec {totals['nosec']}"
    )
    serious = [
        f"{x['issue_severity']} {x['test_id']} {x['filename']}:{x['line_number']}: {x['issue_text']}"
        for x in r["results"]
        if x["issue_severity"] in ("HIGH", "MEDIUM")
    ]
    assert serious == []
    assert totals["loc"] > 20_000  # the whole package was read
    # every `# nosec` names the check it silences and why, in one line
    bare = []
    for folder in FOLDERS:
        for f in sorted((REPO / folder).rglob("*.py")):
            for n, line in enumerate(f.read_text().splitlines(), 1):
                m = NOSEC.search(line)
                if m and not JUSTIFIED.match(m.group(1)):
                    bare.append(f"{f.relative_to(REPO)}:{n}: {line.strip()}")
    assert bare == [], "a # nosec without 'BXXX: why'"
    # each skip in pyproject.toml's [tool.bandit] comes with a comment naming it
    section = (REPO / "pyproject.toml").read_text().split("[tool.bandit]", 1)[1].split("\n[", 1)[0]
    skips = re.findall(r"B\d{3}", section.split("skips", 1)[1].split("]", 1)[0])
    comments = "".join(line for line in section.splitlines() if line.lstrip().startswith("#"))
    assert all(s in comments for s in skips), (skips, comments)


def test_the_xml_justification_holds_expat_refuses_entity_amplification_and_external_entities():
    laughs = (
        '<?xml version="1.0"?><!DOCTYPE l [<!ENTITY a "aaaaaaaaaa">'
        + "".join(f'<!ENTITY {chr(98 + i)} "' + f"&{chr(97 + i)};" * 10 + '">' for i in range(9))
        + "]><root>&j;</root>"
    )
    with pytest.raises(ET.ParseError, match="amplification"):
        ET.fromstring(laughs)
    with pytest.raises(ET.ParseError):
        ET.fromstring('<?xml version="1.0"?><!DOCTYPE r [<!ENTITY x SYSTEM "file:///etc/passwd">]><r>&x;</r>')
