"""The progress bar of every command that runs longer than a few seconds (`evaluate`, `ablation`,
`robustness`, `play --out`, `motion import`): one helper, so they all look and behave alike.

On a terminal: a live bar with the count, the rate and the time left (tqdm), on stderr. Anywhere
else (a pipe, a log file, pytest): nothing while it runs and one final line on stderr, so piped
and captured output stays clean and a log still says how long the work took. Results and other
lines stay on stdout (`Progress.write` prints one above the bar without breaking it).
"""

from __future__ import annotations

import os
import sys
import time
from typing import Callable, TextIO

from tqdm import tqdm


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s" if m else f"{s}s"


def _is_terminal(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # a closed or stand-in stream
        return False


def _size(stream: TextIO) -> tuple[int, int]:
    """The terminal's (columns, rows); (0, 0) when it says none."""
    try:
        return tuple(os.get_terminal_size(stream.fileno()))
    except (AttributeError, ValueError, OSError):
        return 0, 0


class Progress:
    """`total` units of work under `label`; `update(n)` or `set(done)` as they finish, `close()`
    (or the end of a `with` block) at the end. `stream`: where the bar goes (default stderr)."""

    def __init__(self, label: str, total: int, unit: str = "it", stream: TextIO | None = None) -> None:
        self.label, self.total, self.unit = label, int(total), unit
        self.stream = stream if stream is not None else sys.stderr
        self.done = 0
        self.t0 = time.monotonic()
        self.closed = False
        self.bar = None
        if _is_terminal(self.stream):
            sized = min(_size(self.stream)) > 0  # a terminal of no size (`script`, some CI ptys): a fixed one
            self.bar = tqdm(total=self.total, desc=label, unit=f" {unit}", file=self.stream, dynamic_ncols=sized,
                            ncols=None if sized else 100, nrows=None if sized else 24, mininterval=0.5, leave=True)

    def set(self, done: int, total: int | None = None) -> None:
        """`done` units finished so far (and a new `total`, if the work turned out larger)."""
        if total is not None and int(total) != self.total:
            self.total = int(total)
            if self.bar is not None:
                self.bar.total = self.total
        if self.bar is not None:
            self.bar.update(int(done) - self.done)
        self.done = int(done)

    def update(self, n: int = 1) -> None:
        self.set(self.done + n)

    def callback(self, offset: int = 0) -> Callable[[int, int], None]:
        """A `progress(done, total)` for `harness.run_jobs` and what calls it: the units it reports
        count after `offset` (work of several such calls adds up on one bar)."""
        return lambda done, total: self.set(offset + done)

    def write(self, line: str) -> None:
        """One line on stdout, above a live bar."""
        if self.bar is not None:
            self.bar.write(line, file=sys.stdout)
        else:
            print(line, flush=True)

    def close(self) -> None:
        """End the bar (it stays on the terminal), or elsewhere print the one final line."""
        if self.closed:
            return
        self.closed = True
        if self.bar is not None:
            self.bar.close()
        else:
            print(f"{self.label} {self.done}/{self.total} {self.unit} in {_duration(time.monotonic() - self.t0)}",
                  file=self.stream, flush=True)

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
