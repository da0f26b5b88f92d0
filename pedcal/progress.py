"""Progress of long work, through :mod:`logging`.

Library code reports progress as INFO records of its module's logger, and marks those that count
toward an end with ``extra={"progress": (done, total)}``. Nothing is shown
unless the caller asks (``progress=True``) and a handler is configured; the command line installs
:class:`ProgressHandler`, which draws marked records as one updating bar line when stderr is a
terminal, and writes every record as a plain line otherwise (a log file, a pipe, CI).
"""

from __future__ import annotations

import logging
import sys

BAR_WIDTH = 24


class ProgressHandler(logging.StreamHandler):
    """Writes to the current ``sys.stderr`` (not the one at creation, so redirections apply);
    progress records become a bar redrawn in place on a terminal."""

    def __init__(self):
        super().__init__()
        self._open_bar = False

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, _value):
        pass

    def emit(self, record: logging.LogRecord) -> None:
        progress = getattr(record, "progress", None)
        try:
            tty = self.stream.isatty()
        except (AttributeError, ValueError):
            tty = False
        if progress is None or not tty:
            if self._open_bar:
                self.stream.write("\n")
                self._open_bar = False
            super().emit(record)
            return
        try:
            done, total = progress
            frac = min(max(done / total, 0.0), 1.0) if total > 0 else 1.0
            filled = int(round(BAR_WIDTH * frac))
            line = f"{self.format(record)} [{'#' * filled}{'.' * (BAR_WIDTH - filled)}] {100 * frac:3.0f}%"
            self.stream.write("\r\x1b[K" + line)
            self._open_bar = done < total
            if not self._open_bar:
                self.stream.write("\n")
            self.flush()
        except Exception:  # noqa: BLE001 (logging's contract: a handler never raises)
            self.handleError(record)
