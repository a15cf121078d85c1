"""Ctrl-C and SIGTERM: finish the iteration, checkpoint, stop everything, exit 0.

The first signal asks the loop to stop; every wait of the loop is bounded (the receive loop,
the sampler's timeouts, the drain at stop), so the checkpoint follows within seconds whatever
the sockets are doing. A second signal cuts the iteration short with `Interrupted`, which the
training loop answers with an immediate checkpoint (never mid-write: while one is being
written, a further signal is only reported). Before, a second signal raised KeyboardInterrupt
and exited without any checkpoint.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Iterator


class Interrupted(KeyboardInterrupt):
    """A second stop signal: the training loop checkpoints at once and skips the drain."""


class StopFlag:
    """Set by SIGINT/SIGTERM (or `request`); a second signal raises `Interrupted`."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.previous: dict[int, object] = {}
        self.signal_name = ""
        """The signal that stopped the run ("" when a hook or the budget did)."""
        self.at = 0.0
        """`time.monotonic()` of the first stop request."""
        self.saving = False
        """True while a checkpoint is written: a signal then must not cut it in half."""
        self._held = 0
        """Depth of `held` blocks running now."""
        self._deferred = ""
        """The second signal that a `held` block put off ("" when none)."""

    def install(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            self.previous[sig] = signal.signal(sig, self._handle)

    def _handle(self, signum, frame) -> None:
        name = signal.Signals(signum).name
        if self.event.is_set():
            if self.saving:
                print(f"\n[morphmimic] {name}: the checkpoint is being written; stopping right after it", flush=True)
                return
            self._deferred = name
            if not self._held:
                self._interrupt()
            return
        print(f"\n[morphmimic] {name}: checkpointing and stopping (again to hurry)", flush=True)
        self.signal_name = name
        self.at = time.monotonic()
        self.event.set()

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        """Bookkeeping that a second signal must not cut in half (an unroll counted received and
        not yet handed on, say): its `Interrupted` is raised when the block ends, not inside it.
        Keep such blocks short; they may nest."""
        self._held += 1
        try:
            yield
        finally:
            self._held -= 1
        if not self._held and self._deferred:
            self._interrupt()

    def _interrupt(self) -> None:
        name, self._deferred = self._deferred, ""
        print(f"\n[morphmimic] {name} again: checkpointing now, skipping the drain", flush=True)
        raise Interrupted

    def request(self) -> None:
        """Stop the run as Ctrl-C would (for hooks and benchmarks that decide to end it)."""
        if not self.event.is_set():
            self.at = time.monotonic()
        self.event.set()

    def restore(self) -> None:
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)

    def __bool__(self) -> bool:
        return self.event.is_set()
