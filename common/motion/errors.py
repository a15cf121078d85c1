"""The one error type of the motion library.

Importers and loaders raise `ClipError` with the file, the frame (0-based), the joint or
channel, what was found and what was expected, so a user can fix the file without a debugger
(STYLE.md rule 9). It subclasses `ValueError` because a malformed clip is a bad value.
"""

from __future__ import annotations

from pathlib import Path


class ClipError(ValueError):
    """A motion file or clip that cannot be used, with where and why."""

    def __init__(
        self,
        message: str,
        *,
        path: str | Path | None = None,
        frame: int | None = None,
        joint: str | None = None,
    ) -> None:
        where = []
        if path is not None:
            where.append(str(path))
        if frame is not None:
            where.append(f"frame {frame}")
        if joint is not None:
            where.append(f"joint/channel {joint!r}")
        prefix = (", ".join(where) + ": ") if where else ""
        super().__init__(prefix + message)
        self.path = None if path is None else str(path)
        self.frame = frame
        self.joint = joint
