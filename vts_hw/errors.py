"""Errors a user can cause. The CLI turns each into one sentence and a non-zero exit."""


class VtsError(Exception):
    """Base of every error that the CLI reports as one clear sentence (no traceback)."""

    exit_code = 1


class ConfigError(VtsError):
    """A bad rig.yaml: the message names the file, the key and what was expected."""

    exit_code = 2


class DataError(VtsError):
    """A file that cannot be read as what it claims to be (JPEG, MJPEG, recording)."""

    exit_code = 3


class DeviceError(VtsError):
    """A device that cannot be reached or answers wrongly. Subclassed per failure."""

    exit_code = 4


class UsageError(VtsError):
    """A command asked for something it must not do (e.g. write over an existing recording)."""

    exit_code = 2
