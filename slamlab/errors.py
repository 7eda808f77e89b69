"""Errors a user can cause and fix: bad files and bad config values.

The CLI prints these as one clear message (no stack trace); anything else is a bug.
"""

from __future__ import annotations


class SlamlabError(Exception):
    """Base class for user-facing errors."""


class DataError(SlamlabError):
    """A data file is unusable: names the file, the record and the field.

    Example message: ``intel.clf: line 1234 (FLASER), field 'odom_theta': expected a number, got 'nan?'``
    """

    def __init__(self, path: object, message: str, record: object | None = None, field: str | None = None):
        self.path = str(path)
        self.message = message
        self.record = record
        self.field = field
        where = self.path
        if record is not None:
            where += f": {record}"
        if field is not None:
            where += f", field '{field}'"
        super().__init__(f"{where}: {message}")


class ConfigError(SlamlabError):
    """A config value is impossible: names the config key (e.g. ``resampler.threshold``)."""

    def __init__(self, key: str, message: str):
        self.key = key
        super().__init__(f"config '{key}': {message}")
