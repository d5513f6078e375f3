"""Writing rig.yaml: a new skeleton (`vts discover -o`), and locked_params set in place
(`vts camera setup`), the calibration paths set in place (`vts commission`), never losing the
file that was there.

* :func:`write_new` writes a file that must not exist yet: the text goes to a hidden temporary
  file beside it, and is linked to its name only if that name is still free (a file that
  appeared meanwhile is never replaced).
* :func:`set_locked_params` reads rig.yaml with ruamel.yaml's round-trip loader (its comments,
  key order and quoting kept), replaces the ``locked_params`` of the cameras named, checks that
  the result is still a valid rig config, copies the old file to ``rig.yaml.bak`` and writes
  the new one atomically (:func:`vts_hw.files.write_atomic`). A file changed by someone else
  between the read and the write is refused, not overwritten.
* :func:`set_calibration` points ``calibration.cameras`` / ``calibration.mapping`` at new files
  the same way (one machinery, :func:`_rewrite`), as absolute paths; nothing is written when
  rig.yaml names those files already.
"""

from __future__ import annotations

import hashlib
import io
import os
import secrets
import time
from pathlib import Path

import yaml

from vts_hw.config import MAX_CONFIG_BYTES, OLD_CALIBRATION_KEYS, _read_text, parse_rig
from vts_hw.errors import ConfigError, UsageError
from vts_hw.files import WriteFailed, check_target, os_reason, write_atomic

BACKUP_SUFFIX = ".bak"


def skeleton(
    cameras: list[dict], *, password_env: str, user: str = "root", rig: str = "vts", when: float | None = None
) -> str:
    """The text of a rig.yaml for ``cameras`` (dicts: name, host, port, scheme, model, serial,
    firmware, confirmed), with a comment per camera saying what it is; checked to load."""
    stamp = time.strftime("%Y-%m-%d %H:%M", time.localtime(time.time() if when is None else when))
    lines = [
        f"# rig.yaml written by `vts discover` on {stamp}: the Axis cameras that announced themselves.",
        "# Check each entry (name, led_port), set the password variable, then run `vts camera setup --all`",
        "# (it sets each camera and writes what it set as the camera's locked_params, which the daily QA checks).",
        f"rig: {rig}",
        "cameras:",
    ]
    for c in cameras:
        what = ", ".join(
            x
            for x in (
                c.get("model") or "Axis camera",
                f"serial {c.get('serial') or '?'}",
                f"firmware {c.get('firmware') or '?'}",
            )
            if x
        )
        how = "confirmed over VAPIX" if c.get("confirmed") else "as announced, NOT confirmed over VAPIX"
        lines += [f"  # {what} ({how})", f"  - name: {c['name']}", f"    host: {c['host']}"]
        if c.get("scheme", "http") != "http":
            lines.append(f"    scheme: {c['scheme']}")
        lines += [f"    port: {int(c['port'])}", f"    user: {user}", f"    password_env: {password_env}"]
    lines += ["trigger:", "  backend: none"]
    text = "\n".join(lines) + "\n"
    parse_rig(yaml.safe_load(text), "the rig.yaml skeleton")  # what is written loads
    return text


def refuse_existing(path: str | os.PathLike) -> None:
    """UsageError (exit 2) when ``path`` exists (a dangling link too): a rig config is never overwritten."""
    if os.path.lexists(path):
        raise _exists(path)


def _exists(path) -> UsageError:
    return UsageError(f"{path} already exists: a rig config is never overwritten; give -o a new file name")


def write_new(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path``, which must not exist (UsageError, exit 2, if it does: nothing
    is written); WriteFailed (exit 3) when it cannot be written."""
    path = Path(path)
    refuse_existing(path)
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.new")  # a name no one had
    try:
        write_atomic(tmp, text)
        try:
            os.link(tmp, path)  # fails if the name was taken meanwhile: never replaces a file
        except FileExistsError:
            raise _exists(path) from None
        except OSError as exc:
            raise WriteFailed(path, os_reason(exc), "nothing was written") from None
    finally:
        try:
            tmp.unlink()
        except FileNotFoundError:
            pass
    return path


def check_rewritable(path: str | os.PathLike) -> None:
    """Before any work whose result goes into the rig.yaml at ``path`` (a camera set up, a
    calibration): rig.yaml and rig.yaml.bak must be regular files (or the backup absent); a
    device, FIFO, folder or symbolic link is refused (files.NotReplaced, exit 3): rig.yaml is
    replaced whole, and a symbolic link would be replaced by a file, not followed."""
    path = Path(path)
    check_target(path, f"{path} is unchanged")
    check_target(path.with_name(path.name + BACKUP_SUFFIX), f"{path} is unchanged")


def _rewrite(path: str | os.PathLike, edit, *, what: str, during: str, again: str) -> Path | None:
    """rig.yaml at ``path`` read with ruamel.yaml's round-trip loader (comments, key order and
    quoting kept), changed by ``edit(data)`` (False: nothing to change, nothing written, None
    returned), checked to load as a rig config, refused when someone changed the file meanwhile
    (``during``: while what; ``again``: what to do), the old text copied to rig.yaml.bak, the new
    written atomically; returns the backup's path. ``what``: what the new text holds (messages)."""
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    path = Path(path)
    check_rewritable(path)
    text = _read_text(path)
    digest = hashlib.sha256(text.encode("utf-8")).hexdigest()
    rt = YAML()
    rt.preserve_quotes = True
    rt.width = 4096
    try:
        data = rt.load(text)
    except YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if edit(data) is False:
        return None
    out = io.StringIO()
    rt.dump(data, out)
    new_text = out.getvalue()
    if len(new_text.encode("utf-8")) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{path}: the config with its {what} would be larger than a rig config can be")
    parse_rig(yaml.safe_load(new_text), str(path))  # never write a file that would not load
    if hashlib.sha256(_read_text(path).encode("utf-8")).hexdigest() != digest:
        raise UsageError(f"{path} was changed while {during}: it is left as it is; {again}")
    backup = path.with_name(path.name + BACKUP_SUFFIX)
    write_atomic(backup, text, kept=f"{path} is unchanged")
    write_atomic(path, new_text, kept=f"{path} is unchanged; its old text is also in {backup}")
    return backup


def set_locked_params(path: str | os.PathLike, params: dict[str, dict[str, str]]) -> Path:
    """Set ``locked_params`` of the cameras named in ``params`` (camera name -> VAPIX parameter
    -> value) in the rig.yaml at ``path``, keeping its comments; returns the backup's path."""
    from ruamel.yaml.comments import CommentedMap
    from ruamel.yaml.scalarstring import SingleQuotedScalarString

    def edit(data):
        cameras = data.get("cameras") if hasattr(data, "get") else None
        entries = {c.get("name"): c for c in cameras or [] if hasattr(c, "get")}
        for name, values in params.items():
            if name not in entries:
                raise ConfigError(f"{path}: no camera named {name!r} in cameras")
            # quoted: a YAML 1.1 reader (PyYAML: how rig.yaml is loaded) would read no, yes, on, off as booleans
            entries[name]["locked_params"] = CommentedMap(
                (k, SingleQuotedScalarString(str(v))) for k, v in values.items()
            )

    backup = _rewrite(
        path, edit, what="locked parameters", during="the cameras were being set", again="run the setup again"
    )
    assert backup is not None, "edit never returns False: the parameters are always written"
    return backup


CALIBRATION_KEYS = ("cameras", "mapping")  # rig.yaml's calibration: entries (config.CalibrationPaths)


def names_file(path: str | os.PathLike, entry, file: str | os.PathLike) -> bool:
    """Whether a calibration ``entry`` of the rig.yaml at ``path`` already names ``file`` (a
    relative entry is the file beside rig.yaml, as config.load_rig reads it)."""
    if entry is None:
        return False
    entry = os.path.join(os.path.dirname(os.path.abspath(path)), str(entry))
    try:
        return os.path.samefile(entry, file)
    except OSError:
        return os.path.normpath(entry) == os.path.abspath(file)


def set_calibration(path: str | os.PathLike, files: dict[str, str | os.PathLike]) -> Path | None:
    """Point rig.yaml's ``calibration:`` entries (``cameras``: the camera calibration; ``mapping``:
    the VTS -> SPECT mapping; each written under the name the file already uses for it, its old name
    ``stereo`` or ``spect`` in an older file) at ``files``, in place as :func:`set_locked_params` writes (comments
    kept, rig.yaml.bak, atomic, a file changed meanwhile refused). Returns the backup's path, or
    None when rig.yaml names those files already (nothing written)."""
    from ruamel.yaml.comments import CommentedMap

    unknown = sorted(set(files) - set(CALIBRATION_KEYS))
    if unknown:
        raise ValueError(f"no calibration entry {unknown[0]!r} (known: {', '.join(CALIBRATION_KEYS)})")

    def edit(data):
        if not hasattr(data, "get"):
            raise ConfigError(f"{path}: not a rig config (its top level is not a mapping)")
        section = data.get("calibration")
        old_name = {new: old for old, new in OLD_CALIBRATION_KEYS.items()}
        # the file's own name of each entry: an old rig.yaml keeps its old key (not both at once)
        written = {k: old_name[k] if hasattr(section, "get") and old_name[k] in section else k for k in files}
        todo = {
            k: f
            for k, f in files.items()
            if not names_file(path, section.get(written[k]) if hasattr(section, "get") else None, f)
        }
        if not todo:
            return False
        if not isinstance(section, CommentedMap):  # absent, or `calibration:` with nothing under it
            section = data["calibration"] = CommentedMap()
        for key, f in todo.items():
            section[written[key]] = os.path.abspath(f)  # one no reader need resolve
        return True

    return _rewrite(
        path,
        edit,
        what="calibration paths",
        during="its calibration paths were being set",
        again="run the step again (`vts commission --from STEP`)",
    )


__all__ = [
    "skeleton",
    "refuse_existing",
    "check_rewritable",
    "write_new",
    "set_locked_params",
    "set_calibration",
    "names_file",
    "CALIBRATION_KEYS",
    "BACKUP_SUFFIX",
]
