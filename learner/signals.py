"""Ctrl-C and SIGTERM: finish the iteration, checkpoint, stop everything, exit 0."""

from __future__ import annotations

import signal
import threading


class StopFlag:
    """Set by SIGINT/SIGTERM; a second signal forces an immediate KeyboardInterrupt."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.previous: dict[int, object] = {}

    def install(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            self.previous[sig] = signal.signal(sig, self._handle)

    def _handle(self, signum, frame) -> None:
        if self.event.is_set():
            raise KeyboardInterrupt
        print(f"\n[morphmimic] {signal.Signals(signum).name}: checkpointing and stopping (again to force)", flush=True)
        self.event.set()

    def request(self) -> None:
        """Stop the run as Ctrl-C would (for hooks and benchmarks that decide to end it)."""
        self.event.set()

    def restore(self) -> None:
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)

    def __bool__(self) -> bool:
        return self.event.is_set()
