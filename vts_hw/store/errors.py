"""The store's one user-facing error."""

from vts_hw.errors import DataError


class StoreError(DataError):
    """A results database that cannot be opened or used as one; the message is one sentence
    naming the database (its URL with any password masked)."""
