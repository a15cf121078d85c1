"""A durable per-actor unroll sequence number, so a restarted actor continues the numbering of
the process it replaces instead of starting again at 0.

The number of the next unroll is written (write-ahead) before the unroll is sent. When Ray
restarts a crashed actor, the new process reads the ledger and continues from there, so the
unrolls the dead process had queued but never delivered show up at the learner as a sequence
gap: counted, not silently lost. The ledger is a small file per actor id in a directory every
actor of the run can reach (the run directory when all nodes are on one machine); without a
directory, numbering restarts at 0 and such in-flight losses are bounded by the send HWM but
not counted.
"""

from __future__ import annotations

import os
from pathlib import Path


class SeqLedger:
    def __init__(self, directory: str, actor_id: int):
        self.path = Path(directory) / f"actor-{actor_id}.seq" if directory else None
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)

    def next_seq(self) -> int:
        """The first sequence number this incarnation should use."""
        if self.path is None:
            return 0
        raw = os.pread(self._fd, 32, 0).strip(b"\0 \n")
        return int(raw) + 1 if raw.isdigit() else 0

    def record(self, seq: int) -> None:
        """Write-ahead: `seq` is about to be sent. A kill after this line makes it a counted gap."""
        if self.path is not None:
            os.pwrite(self._fd, f"{seq:020d}".encode(), 0)

    def close(self) -> None:
        if self.path is not None:
            os.close(self._fd)
            self.path = None
