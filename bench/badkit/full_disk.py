"""The class "full disk" of bench/bad_inputs.py (issue 21 §5): every command that writes, run
against a real full disk.

Each case mounts a small tmpfs of its own in its folder (as tests/fsfaults.py does: root, or
password-less sudo), fills it (or leaves a little room, so that a recording or an export gets
under way first), points the command's output at it, and judges:

* exit 3 with one sentence on stderr starting ``vts:`` and naming the file (its path on the full
  disk); exit 0 is a false OK;
* no half file that looks whole on that disk: no temporary file, no empty file, every JSON,
  CSV, JPEG, PNG, HTML, YAML and SQLite file left there reads whole, and a recording left there
  holds every frame its index and manifest promise (vts_hw.recording.promised);
* nothing already acquired lost: the case's own check (the analysis stored, the calibration in
  its fallback file, the unsaved run still there, the inputs unchanged).

The inputs (a simulated rig running detached, a rendered patient recording, a results store
with runs, the real checkerboard pairs) are made once by :func:`setup` in subprocesses (no
thread in the process that forks the cases); :func:`cleanup` unmounts every disk and stops the
rig.
"""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

from badkit.classes import Case, Verdict, common, sha, shared_data

CLASS = "full disk"
DISK = "disk"
PY = sys.executable
_TESTS = Path(__file__).resolve().parents[2] / "tests"
sys.path.insert(0, str(_TESTS))
from fsfaults import SmallDisk, root_cmd  # noqa: E402  (the tests' own full disk: the same mount and filler)


def available() -> str:
    """'' when a tmpfs can be mounted here, else why not."""
    return "" if root_cmd() is not None else "needs root or password-less sudo to mount a small tmpfs"


def _mount(path: Path, size_kb: int) -> None:
    path.mkdir(parents=True, exist_ok=True)
    subprocess.run(
        [*root_cmd(), "mount", "-t", "tmpfs", "-o", f"size={size_kb}k,mode=0777", "tmpfs", str(path)],
        check=True,
        capture_output=True,
    )


def _fill(path: Path, leave: int = 0) -> None:
    SmallDisk(path, 0).fill(leave)


def cleanup(root: Path) -> None:
    """Every disk mounted under ``root`` unmounted (lazily), the rig of :func:`setup` stopped."""
    sim = root / "fd-inputs" / "sim"
    if (sim / "sim.pid").exists():
        subprocess.run([PY, "-m", "vts_hw.cli", "sim", "down", "--dir", str(sim)], capture_output=True, timeout=60)
    prefix = str(root.resolve())
    for line in Path("/proc/mounts").read_text().splitlines():
        where = line.split()[1].replace("\\040", " ")
        if where.startswith(prefix):
            subprocess.run([*(root_cmd() or []), "umount", "-l", where], capture_output=True)


# -- the inputs ------------------------------------------------------------------------------

_SESSION = """
import json, sys
from pathlib import Path
import numpy as np
from vts_hw.sim_devices.recording_sim import simulate_recording
from vts_hw.sim_devices.patient import BodyMove
from vts_hw.vision.registration import RigidTransform
out = Path(sys.argv[1]); start = 1_790_000_000.0 + 5.0
sim = simulate_recording(out / "session", duration_s=14.0, seed=0,
                         patient={"moves": [BodyMove(start + 8, start + 8.8, (0.3, 0.2, 0.7), (1, 2, 1))]})
cams = [{"name": n, **{k: np.asarray(getattr(c, k)).tolist() for k in ("K", "dist", "R", "t")}}
        for n, c in ((n, sim.scene.camera_at(n, start)) for n in sim.cameras)]
(out / "cameras.json").write_text(json.dumps({"unit": "mm", "cameras": cams}))
RigidTransform.identity().save(out / "mapping.json")
simulate_recording(out / "small", duration_s=1.0, seed=1, add_band=False)
"""

_STORE = """
import sys
from vts_hw.store import ResultsStore
with ResultsStore(sys.argv[1]) as s:
    for day in range(3):
        with s.begin_run("daily", rig="room", started=1.79e9 + 86400 * day) as h:
            h.measure("cam1", "drift_x_px", 0.1 * day, "px")
            h.measure("cam1", "drift_y_px", -0.1 * day, "px")
            h.finish(status="OK", finished=1.79e9 + 86400 * day + 5)
"""


class Inputs:
    """What the cases read, made once (in subprocesses); ``env``: the rig's password variables."""

    def __init__(self, root: Path):
        self.dir = d = root / "fd-inputs"
        d.mkdir(parents=True, exist_ok=True)
        self.sim = d / "sim"
        p = subprocess.run(
            [PY, "-m", "vts_hw.cli", "sim", "up", "--detach", "--dir", str(self.sim)],
            capture_output=True,
            text=True,
            timeout=180,
        )
        if p.returncode != 0:
            raise RuntimeError(f"vts sim up failed: {p.stderr.strip()}")
        from vts_hw.sim_devices.rig import load_env_file

        self.env = load_env_file(self.sim / "sim.env")
        self.config = str(self.sim / "rig.yaml")
        subprocess.run([PY, "-c", _SESSION, str(d)], check=True, capture_output=True, timeout=600)
        self.session, self.small = d / "session", d / "small"
        self.cameras, self.mapping = d / "cameras.json", d / "mapping.json"
        self.store = d / "runs.sqlite"
        subprocess.run([PY, "-c", _STORE, f"sqlite:///{self.store}"], check=True, capture_output=True, timeout=120)
        self.boards = shared_data() / "stereo-checkerboard"
        self.digest = self._digest()

    def baseline_store(self) -> Path:
        """A store holding a drift baseline of the rig (made on first use): what `qa daily` needs."""
        db = self.dir / "baseline.sqlite"
        if not db.exists():
            p = subprocess.run(
                [
                    PY,
                    "-m",
                    "vts_hw.cli",
                    "--store",
                    f"sqlite:///{db}",
                    "qa",
                    "drift",
                    "--set-baseline",
                    "--config",
                    self.config,
                ],
                capture_output=True,
                text=True,
                timeout=300,
                env=self.env_all,
            )
            if p.returncode != 0:
                raise RuntimeError(f"vts qa drift --set-baseline failed: {p.stderr.strip()[-300:]}")
        return db

    @property
    def env_all(self) -> dict[str, str]:
        return {**os.environ, **self.env}

    def _digest(self) -> dict[str, str]:
        """Every input file's sha256: no case may change one."""
        return {
            str(p): sha(p)
            for p in sorted(self.dir.rglob("*"))
            if p.is_file() and "sim" not in p.relative_to(self.dir).parts
        }

    def changed(self) -> list[str]:
        now = self._digest()
        return [Path(p).name for p, h in self.digest.items() if now.get(p) != h]


# -- what a full disk may leave behind -------------------------------------------------------


def half_files(disk: Path) -> list[str]:
    """Files on the disk that look whole but are not (or are temporary, or empty)."""
    bad = []
    folders = set()
    for p in sorted(disk.rglob("*")):
        if not p.is_file() or p.name == ".filler":
            continue
        rel = str(p.relative_to(disk))
        why = _not_whole(p)
        if why:
            bad.append(f"{rel}: {why}")
        if p.suffix == ".mjpeg" or p.name.endswith(".index.csv"):
            folders.add(p.parent)
    for f in folders:
        from vts_hw.recording.promised import folder_summaries, shortfall

        try:
            short = shortfall(folder_summaries(f))
        except Exception as exc:  # noqa: BLE001 -- any failure to read it is what is reported
            short = f"unreadable ({exc})"
        if short:
            bad.append(f"{f.relative_to(disk)}: not whole ({short})")
    return bad


def _not_whole(p: Path) -> str:
    name, data = p.name, p.read_bytes()
    if ".tmp" in name or name.endswith("~"):
        return "a temporary file left behind"
    if not data:
        return "empty"
    try:
        if name.endswith(".json"):
            json.loads(data)
        elif name.endswith((".jpg", ".jpeg")) and not (
            data[:2] == b"\xff\xd8" and data.rstrip(b"\0")[-2:] == b"\xff\xd9"
        ):
            return "a cut JPEG"
        elif name.endswith(".png") and not data.endswith(b"IEND\xaeB`\x82"):
            return "a cut PNG"
        elif name.endswith(".pdf") and b"%%EOF" not in data[-64:]:
            return "a cut PDF"
        elif name.endswith(".html") and b"</html>" not in data[-64:]:
            return "a cut HTML page"
        elif name.endswith((".yaml", ".yml")):
            import yaml

            yaml.safe_load(data)
        elif name.endswith(".csv") and not name.endswith(".index.csv"):
            if not data.endswith(b"\n") or len({line.count(b",") for line in data.splitlines()[1:] if line}) > 1:
                return "a cut CSV"
        elif name.endswith((".sqlite", ".db")):
            con = sqlite3.connect(f"file:{p}?mode=ro", uri=True)
            try:
                ok = con.execute("PRAGMA integrity_check").fetchone()[0]
            finally:
                con.close()
            if ok != "ok":
                return f"a damaged database ({ok})"
    except Exception as exc:  # noqa: BLE001 -- a file that does not read is the finding
        return f"does not read whole ({type(exc).__name__})"
    return ""


# -- the cases ---------------------------------------------------------------------------------


def _judge(extra=None):
    """Exit 3, one sentence naming a file on the disk, no half file there, inputs unchanged, and
    ``extra(wd, out, err) -> str`` (what was acquired and lost; '' when nothing)."""

    def judge(wd: Path, code, out, err) -> Verdict:
        v = common(code, err)
        disk = wd / DISK
        if v.hang:
            return v
        if v.traceback:  # counted, and what it left on the disk too
            half = half_files(disk)
            if half:
                v.damaged, v.why = True, f"{v.why}; {'; '.join(half)}"
            return v
        last = (err.strip().splitlines() or [""])[-1]
        if code == 0:
            return Verdict(false_ok=True, why=f"exit 0 on a full disk: {last[:160]}")
        half = half_files(disk)
        lost = extra(wd, out, err) if extra else ""
        changed = INPUTS.changed() if INPUTS else []
        if half or lost or changed:
            return Verdict(
                damaged=True,
                why="; ".join(
                    [
                        *half,
                        *([lost] if lost else []),
                        *([f"input(s) changed: {', '.join(changed)}"] if changed else []),
                    ]
                ),
            )
        if code != 3 or not last.startswith("vts: ") or str(disk) not in last:
            return Verdict(
                other=True, why=f"exit {code} without one sentence naming a file on the full disk: {last[:200]}"
            )
        return v

    return judge


def _runs(db: Path, procedure: str) -> int:
    if not db.exists():
        return 0
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return con.execute("SELECT count(*) FROM runs WHERE procedure = ?", (procedure,)).fetchone()[0]
    finally:
        con.close()


def _stored(procedure: str):
    """The result reached the case's own store (beside the disk), or an unsaved file."""

    def check(wd, out, err):
        if _runs(wd / "own.sqlite", procedure) == 1 or list(wd.rglob("unsaved/*.json")):
            return ""
        return f"the {procedure} result was neither stored nor kept in an unsaved file"

    return check


def _fallback(stem: str):
    def check(wd, out, err):
        found = [p for p in wd.glob(f"{stem}-*.json")]
        if found and not _not_whole(found[0]):
            return ""
        return f"the {stem} was not kept in a fallback file ({stem}-<time>.json in the current folder)"

    return check


def _unsaved_kept(wd, out, err):
    return "" if (wd / "unsaved-run.json").exists() else "the unsaved run file was renamed although not stored"


def _recorded(wd, out, err):
    """The disk filled while recording: frames were kept (and are whole: half_files)."""
    rec = wd / DISK / "rec"
    n = sum(1 for _ in open(rec / "cam1.index.csv")) - 1 if (rec / "cam1.index.csv").exists() else 0
    return "" if n > 0 else "no frame kept although the disk had room for some"


INPUTS: Inputs | None = None


def inputs(root: Path) -> Inputs:
    """The inputs of :class:`Inputs`, made once per sweep (the root writes class runs the same
    command lines); the rig's passwords put in the environment the forked cases inherit (the
    sweep restores it)."""
    global INPUTS
    if INPUTS is None or INPUTS.dir != root / "fd-inputs":
        INPUTS = Inputs(root)
    os.environ.update(INPUTS.env)
    return INPUTS


def cases(root: Path, only: str | None = None) -> list[Case]:
    """Every writing command against a full disk (empty when no tmpfs can be mounted)."""
    if available():
        return []
    out = []
    for what, argv, size_kb, leave, extra in table(inputs(root)):
        if only and not what.startswith(only):
            continue

        def make(wd: Path, argv=argv, size_kb=size_kb, leave=leave) -> list[str]:
            disk = wd / DISK
            _mount(disk, size_kb)
            args = argv(wd, disk)  # may put its input on the disk first (reindex)
            _fill(disk, leave)
            return args

        out.append(Case(CLASS, what, make, _judge(extra)))
    return out


def table(inp: Inputs) -> list[tuple]:
    """Every writing command with good inputs, its outputs in a folder D: (what, argv(wd, D),
    size of the disk in kB, bytes left free on it, the check of what was acquired)."""
    cfg = ["--config", inp.config]
    own = lambda wd: ["--store", f"sqlite:///{wd / 'own.sqlite'}"]  # noqa: E731
    from vts_hw.store.unsaved import FORMAT

    unsaved = json.dumps(
        {
            "format": FORMAT,
            "procedure": "daily",
            "rig": "dead",
            "started": 1.8e9,
            "finished": 1.8e9 + 5,
            "state": "OK",
            "measurements": [{"subject": "cam1", "metric": "drift_x_px", "value": 0.1, "unit": "px", "state": "OK"}],
        }
    )
    return [
        # (what, argv(wd, D), size kB, bytes left free, extra check)
        ("camera snapshot", lambda wd, D: ["camera", "snapshot", "cam1", "-o", f"{D}/a.jpg", *cfg], 64, 0, None),
        (
            "camera record, the disk full before the first frame",
            lambda wd, D: ["camera", "record", "cam1", "--seconds", "2", "-o", f"{D}/rec", *cfg],
            64,
            0,
            None,
        ),
        (
            "camera record, the disk filling while recording",
            lambda wd, D: ["camera", "record", "cam1", "--seconds", "4", "-o", f"{D}/rec", *cfg],
            2048,
            600_000,
            _recorded,
        ),
        (
            "scan start",
            lambda wd, D: ["scan", "start", "--duration", "2", "--no-live", "-o", f"{D}/scan", *cfg],
            64,
            0,
            None,
        ),
        (
            "qa daily, the store on the full disk",
            lambda wd, D: ["--store", f"sqlite:///{D}/results.sqlite", "qa", "daily", *cfg],
            64,
            0,
            None,
        ),
        (
            "qa steps --sim",
            lambda wd, D: [
                "qa",
                "steps",
                "--sim",
                "--vertical",
                "1",
                "--axial",
                "1",
                "--frames",
                "1",
                "-o",
                f"{D}/steps",
            ],
            64,
            0,
            None,
        ),
        (
            "calibrate stereo",
            lambda wd, D: [*own(wd), "calibrate", "stereo", str(inp.boards), "--square", "30", "-o", f"{D}/cal.json"],
            64,
            0,
            _fallback("cal"),
        ),
        (
            "motion analyze --export -o --plot",
            lambda wd, D: [
                *own(wd),
                "motion",
                "analyze",
                str(inp.session),
                "--calibration",
                str(inp.cameras),
                "--mapping",
                str(inp.mapping),
                "--export",
                f"{D}/exp",
                "-o",
                f"{D}/motion.html",
                "--plot",
                f"{D}/motion.png",
                "--workers",
                "1",
            ],
            1024,
            200_000,
            _stored("motion"),
        ),
        (
            "recording process",
            lambda wd, D: [
                "recording",
                "process",
                str(inp.session),
                "--calibration",
                str(inp.cameras),
                "-o",
                f"{D}/tracks",
                "--workers",
                "1",
            ],
            64,
            0,
            None,
        ),
        (
            "report drift -o html",
            lambda wd, D: ["--store", f"sqlite:///{inp.store}", "report", "drift", "-o", f"{D}/drift.html"],
            64,
            0,
            None,
        ),
        (
            "report drift -o pdf",
            lambda wd, D: ["--store", f"sqlite:///{inp.store}", "report", "drift", "-o", f"{D}/drift.pdf"],
            64,
            0,
            None,
        ),
        (
            "report rooms",
            lambda wd, D: ["--store", f"sqlite:///{inp.store}", "report", "rooms", "-o", f"{D}/rooms.html"],
            64,
            0,
            None,
        ),
        ("store init", lambda wd, D: ["store", "init", f"{D}/new.sqlite"], 64, 0, None),
        (
            "store migrate --to",
            lambda wd, D: ["store", "migrate", "--from", str(inp.store), "--to", f"{D}/new.sqlite"],
            64,
            0,
            None,
        ),
        (
            "qa import, the store on the full disk",
            lambda wd, D: [
                "--store",
                f"sqlite:///{D}/results.sqlite",
                "qa",
                "import",
                _write(wd / "unsaved-run.json", unsaved),
            ],
            64,
            0,
            _unsaved_kept,
        ),
        ("recording reindex", lambda wd, D: ["recording", "reindex", _copy(inp.small, D / "small")], 2048, 0, None),
        ("sim up --detach", lambda wd, D: ["sim", "up", "--detach", "--dir", f"{D}/sim"], 64, 0, None),
        ("sim up (foreground)", lambda wd, D: ["sim", "up", "--dir", f"{D}/sim"], 64, 0, None),
        ("demo", lambda wd, D: ["demo", "-o", f"{D}/demo", "--days", "1"], 64, 0, None),
    ]


def _write(p: Path, text: str) -> str:
    p.write_text(text)
    return str(p)


def _copy(src: Path, dst: Path) -> str:
    shutil.copytree(src, dst)
    return str(dst)
