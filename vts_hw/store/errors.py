"""The store's one user-facing error."""

from vts_hw.errors import DataError


class StoreError(DataError):
    """A results database that cannot be opened or used as one; the message is one sentence
    naming the database (its URL with any password masked)."""


class NoStore(StoreError):
    """There is no results store where one was to be read (nothing there yet): a reader that can
    do without one (an aim check without a drift baseline) goes on; any other StoreError is not
    that (a database that is not ours, one that cannot be read)."""
