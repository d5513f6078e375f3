"""Registries of file readers, so that a vendor format can be added without touching analyses.

A reader has a ``name``, the file ``extensions`` it claims (lower case, with the dot), a
``sniff(head)`` test on the first bytes of a file and ``read(path)``. A :class:`FormatRegistry`
holds the readers of one kind of file (SPECT volumes, list-mode) and picks one for a path: by
extension then content, or by content then extension, as suits the kind. A later registration
of the same name replaces the earlier one. Every failure is a :class:`DataError` naming the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Generic, Protocol, TypeVar

from vts_hw.bounded import ANY_SIZE, open_checked
from vts_hw.errors import DataError


class Reader(Protocol):
    """What every reader of a registry has (each kind's reader says what its ``read`` returns)."""

    @property
    def name(self) -> str: ...

    @property
    def extensions(self) -> tuple[str, ...]: ...

    def sniff(self, head: bytes, /) -> bool: ...

    def read(self, path: Path, /) -> Any: ...


R = TypeVar("R", bound=Reader)
SNIFF_BYTES = 512


class FormatRegistry(Generic[R]):
    """Readers of one kind of file. ``kind`` names it in messages ("volume", "list-mode");
    ``content_first`` tries ``sniff`` before the extensions; ``check(reader)`` (optional)
    refuses a reader that lacks what the kind needs."""

    def __init__(self, kind: str, content_first: bool = False, check=None, sniff_bytes: int = SNIFF_BYTES):
        self.kind = kind
        self.content_first = content_first
        self.check = check
        self.sniff_bytes = sniff_bytes
        self._readers: dict[str, R] = {}

    def register(self, reader: R) -> None:
        """Add (or replace, by name) a reader."""
        if self.check is not None and not self.check(reader):
            raise TypeError(f"{reader!r} is not a {self.kind} reader (name, extensions, sniff, read)")
        self._readers[reader.name] = reader

    def unregister(self, name: str) -> None:
        """Remove a reader (no error when there is none of that name)."""
        self._readers.pop(name, None)

    def readers(self) -> list[R]:
        """The registered readers, in registration order."""
        return list(self._readers.values())

    def _known(self) -> str:
        return ", ".join(self._readers) or "none"

    def head(self, path: Path) -> bytes:
        try:
            with open_checked(path, ANY_SIZE, "list-mode file") as f:  # a FIFO would block; a device never ends
                return f.read(self.sniff_bytes)
        except OSError as e:
            raise DataError(f"{path}: cannot read ({e.strerror})") from None

    def reader_for(self, path) -> R:
        """The reader for ``path``; DataError if none claims it."""
        path = Path(path)
        ext = path.suffix.lower()
        by_ext = next((r for r in self._readers.values() if ext in r.extensions), None)
        if by_ext is not None and not self.content_first:
            return by_ext
        head = self.head(path)
        for r in self._readers.values():
            if r.sniff(head):
                return r
        if by_ext is not None:
            return by_ext  # it will say what is wrong with the content
        raise DataError(f"{path}: not a {self.kind} file of a known format (known: {self._known()})")

    def read(self, path, fmt: str | None = None):
        """Read ``path`` with the reader ``fmt`` (a name), else the one :meth:`reader_for` picks."""
        path = Path(path)
        if not path.exists():
            raise DataError(f"{path}: no such file")
        if not path.is_file():
            raise DataError(f"{path}: not a file")
        if fmt is not None:
            if fmt not in self._readers:
                raise DataError(f"{path}: unknown {self.kind} format '{fmt}' (known: {self._known()})")
            return self._readers[fmt].read(path)
        return self.reader_for(path).read(path)
