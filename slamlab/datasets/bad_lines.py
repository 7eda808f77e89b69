"""What a text log reader does with a line it cannot read (`dataset.on_bad_line`):

- `error` (default): stop with the file, line and field, and say when the line is the
  file's last one (the file was cut mid-line, e.g. a copy that did not finish);
- `skip`: drop the line, go on, and warn once with the count and the first line numbers.
"""

from __future__ import annotations

import warnings

from slamlab.errors import ConfigError, DataError

MODES = ("error", "skip")
SHOWN = 5  # line numbers named in the skip warning


class BadLines:
    """Collects or raises the bad lines of one file of `n_lines` lines."""

    def __init__(self, path: object, n_lines: int, mode: str = "error", truncated: bool = False):
        if mode not in MODES:
            raise ConfigError("dataset.on_bad_line", f"must be one of {', '.join(MODES)}, got {mode!r}")
        self.path = str(path)
        self.n_lines = n_lines
        self.mode = mode
        self.truncated = truncated  # the file does not end with a newline
        self.skipped: list[tuple[int, DataError]] = []

    def add(self, lineno: int, exc: DataError) -> None:
        """Line `lineno` (1-based) is bad: raise (error mode) or remember it (skip mode)."""
        if self.mode == "error":
            raise self._explained(lineno, exc) from None
        self.skipped.append((lineno, exc))

    def _explained(self, lineno: int, exc: DataError) -> DataError:
        hint = ""
        if lineno == self.n_lines:
            cut = "; it ends without a newline" if self.truncated else ""
            hint = f" (this is the file's last line: the file looks truncated{cut})"
        return DataError(exc.path, f"{exc.message}{hint}; dataset.on_bad_line=skip drops bad lines and goes on",
                         record=exc.record, field=exc.field)  # fmt: skip

    def warn(self) -> None:
        """One warning for all skipped lines (nothing when none were skipped)."""
        if not self.skipped:
            return
        lines = sorted(n for n, _ in self.skipped)
        shown = ", ".join(map(str, lines[:SHOWN])) + (", ..." if len(lines) > SHOWN else "")
        first = min(self.skipped, key=lambda item: item[0])[1]
        last = " (the last line of the file: truncated)" if lines[-1] == self.n_lines else ""
        warnings.warn(f"{self.path}: skipped {len(lines)} bad line(s): {shown}{last}; first: {first}",
                      RuntimeWarning, stacklevel=3)  # fmt: skip
