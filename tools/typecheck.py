"""mypy on the vts_hw package as it is installed: `python tools/typecheck.py [PATH ...]`.

The package is made of several folders (setup.py's PACKAGE_DIR: drivers/ is vts_hw.drivers,
procedures/ is vts_hw.procedures ...). mypy finds modules by folder, and it cannot read the
editable install's import hook, so on the tree as it is `vts_hw.drivers` is a module it cannot
find (and everything imported from it would be Any). This builds a tree of links in which the
folders sit where the package has them (TREE/vts_hw/drivers -> drivers/), runs mypy there with the
project's configuration ([tool.mypy] in pyproject.toml) and prints its messages with the paths of
the checkout again (docs/decisions/0098-mypy.md).

PATH: folders or modules of the checkout to check (default: the whole package, every folder of
PACKAGE_DIR). The modules they import are read but, with --follow-imports=silent (the default
here), their errors are not reported: a part can be clean before the whole is.
--tree DIR keeps the link tree (and mypy's cache under it) for the next run; exit: mypy's own
(0 clean, 1 errors, 2 bad use); 2 also for a PATH outside the package's folders (one sentence).
"""

from __future__ import annotations

import argparse
import ast
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def package_dir(setup_py: Path = REPO / "setup.py") -> dict[str, str]:
    """setup.py's PACKAGE_DIR (package name -> folder), read without running setup.py."""
    for node in ast.parse(setup_py.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "PACKAGE_DIR" for t in node.targets
        ):
            return dict(ast.literal_eval(node.value))
    raise ValueError(f"{setup_py}: no PACKAGE_DIR assignment to read the package's folders from")


def link_tree(tree: Path, repo: Path = REPO) -> dict[str, Path]:
    """TREE/vts_hw/... made of links into the checkout; returns tree path prefix -> checkout folder,
    longest first (to map mypy's paths back)."""
    folders = package_dir(repo / "setup.py")
    prefixes: dict[str, Path] = {}
    for package, folder in sorted(folders.items(), key=lambda kv: kv[0].count(".")):
        where = tree.joinpath(*package.split("."))
        prefixes[where.relative_to(tree).as_posix()] = repo / folder
        if package.count(".") == 0:
            where.mkdir(parents=True, exist_ok=True)
            for entry in (repo / folder).iterdir():
                if entry.name in ("__pycache__",) or entry.name in {p.split(".")[-1] for p in folders}:
                    continue
                _link(where / entry.name, entry)
        else:
            _link(where, repo / folder)
    return dict(sorted(prefixes.items(), key=lambda kv: -len(kv[0])))


def _link(link: Path, target: Path) -> None:
    if link.is_symlink():
        if Path(os.readlink(link)) == target:
            return
        link.unlink()
    link.symlink_to(target, target_is_directory=target.is_dir())


def in_tree(path: str, prefixes: dict[str, Path], repo: Path = REPO) -> str:
    """A checkout path (drivers/axis.py, vts_hw/motion) as it is in the link tree."""
    real = (repo / path).resolve()
    for prefix, folder in prefixes.items():
        if real == folder or folder in real.parents:
            return (Path(prefix) / real.relative_to(folder)).as_posix()
    raise ValueError(
        f"{path}: not in the package's folders ({', '.join(str(f.relative_to(repo)) for f in prefixes.values())})"
    )


def back_to_checkout(text: str, prefixes: dict[str, Path], repo: Path = REPO) -> str:
    """mypy's messages with the link tree's paths written as the checkout's."""

    def one(m: re.Match[str]) -> str:
        path = m.group(0)
        for prefix, folder in prefixes.items():
            if path == prefix or path.startswith(prefix + "/"):
                return (folder.relative_to(repo) / path[len(prefix) :].lstrip("/")).as_posix()
        return path

    pattern = "|".join(re.escape(p) for p in prefixes)
    return re.sub(rf"(?:{pattern})(?:/[\w./-]*)?", one, text)


def mypy(
    paths: list[str], tree: Path, prefixes: dict[str, Path], extra: list[str] | None = None
) -> subprocess.CompletedProcess[str]:
    """mypy on PATHS (checkout paths; none: the whole package) in the link tree at TREE (made by
    link_tree, which gave PREFIXES), with its cache there; its output mapped back to the checkout."""
    targets = [in_tree(p, prefixes) for p in paths] if paths else ["vts_hw"]
    cmd = [
        sys.executable,
        "-m",
        "mypy",
        "--config-file",
        str(REPO / "pyproject.toml"),
        "--cache-dir",
        str(tree / ".mypy_cache"),
        "--follow-imports=silent",
        *(extra or []),
        *targets,
    ]
    p = subprocess.run(cmd, cwd=tree, capture_output=True, text=True)
    return subprocess.CompletedProcess(
        cmd, p.returncode, back_to_checkout(p.stdout, prefixes), back_to_checkout(p.stderr, prefixes)
    )


def run(paths: list[str], tree: Path, extra: list[str] | None = None) -> subprocess.CompletedProcess[str]:
    """The link tree made (or brought up to date) at TREE, and mypy on PATHS in it."""
    return mypy(paths, tree, link_tree(tree), extra)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("paths", nargs="*", help="folders or modules of the checkout (default: the whole package)")
    ap.add_argument("--tree", type=Path, help="keep the link tree and mypy's cache here for the next run")
    args, extra = ap.parse_known_args(argv)
    try:
        if args.tree:
            p = run(args.paths, args.tree.resolve(), extra)
        else:
            with tempfile.TemporaryDirectory(prefix="vts-typecheck-") as tmp:
                p = run(args.paths, Path(tmp), extra)
    except ValueError as exc:
        print(f"typecheck: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"typecheck: --tree {args.tree}: cannot make the tree of links there ({exc.strerror})", file=sys.stderr)
        return 2
    sys.stdout.write(p.stdout)
    sys.stderr.write(p.stderr)
    return p.returncode


if __name__ == "__main__":
    sys.exit(main())
