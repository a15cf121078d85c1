"""Where a run's scalars go (`--logger`): TensorBoard event files under `<run>/tb/` (the default),
or a Weights & Biases run under `<run>/wandb/`. One small interface, `ScalarSink`, so the run log
(`learner.run_log`) writes the same metrics whichever backend the user chose.

W&B is an optional extra (`pip install -e ".[wandb]"`) and is imported only when chosen. It runs
offline unless the user set WANDB_MODE: a training machine often has no network, and an online
`wandb.init` there waits on the network before the first iteration. An offline run is uploaded
later with `wandb sync <run>/wandb/offline-run-*`.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import logging
import os
import uuid
from pathlib import Path
from typing import Any, Protocol

LOGGERS = ("tensorboard", "wandb")
"""The values of `--logger`."""
WANDB_EXTRA = 'pip install -e ".[wandb]"'
"""How a user gets the W&B backend: the project's optional extra."""
WANDB_PROJECT = "morphmimic"
"""The W&B project every run logs to (WANDB_PROJECT overrides it, as W&B documents)."""
WANDB_ID_FILE = "wandb_run_id"
"""In the run directory: the W&B run id, so a resumed run goes on logging to the same W&B run."""


class ScalarSink(Protocol):
    """Takes one iteration's scalars at a step (environment steps) and is closed at the end."""

    def scalars(self, metrics: dict[str, float], step: int) -> None: ...

    def close(self) -> None: ...


def check_logger(name: str) -> None:
    """ValueError in one line when the backend `name` cannot run here: an unknown name, or W&B
    without its package (naming the extra that installs it). Cheap: imports nothing."""
    if name not in LOGGERS:
        raise ValueError(f"--logger {name!r}: give one of {', '.join(LOGGERS)}")
    if name == "wandb" and importlib.util.find_spec("wandb") is None:
        raise ValueError(f"--logger wandb needs the wandb package, an optional extra: {WANDB_EXTRA}")


class TensorBoardSink:
    """Every scalar as a TensorBoard event under `<run_dir>/tb` (`tensorboard --logdir runs`)."""

    def __init__(self, run_dir: Path) -> None:
        from torch.utils.tensorboard import SummaryWriter  # lazy: only the chosen backend is imported (tensorboard)

        self.writer = SummaryWriter(log_dir=str(run_dir / "tb"))

    def scalars(self, metrics: dict[str, float], step: int) -> None:
        for name, value in metrics.items():
            self.writer.add_scalar(name, value, step)

    def close(self) -> None:
        self.writer.close()


class WandbSink:
    """The scalars as one W&B run under `<run_dir>/wandb`: named after the run, its whole
    configuration attached, the same run id on every resume (kept in `<run_dir>/wandb_run_id`).
    Offline unless WANDB_MODE says otherwise; W&B's own console capture is off, so the run's
    console and log.txt stay as they are with TensorBoard."""

    def __init__(self, run_dir: Path, name: str, config: dict[str, Any]) -> None:
        import wandb  # lazy: an optional extra, imported only when --logger wandb is chosen

        logging.getLogger("wandb").setLevel(logging.WARNING)  # its INFO lines would join the run's console
        id_file = run_dir / WANDB_ID_FILE
        run_id = id_file.read_text().strip() if id_file.exists() else uuid.uuid4().hex[:16]
        id_file.write_text(run_id + "\n")
        self.mode = os.environ.get("WANDB_MODE") or "offline"
        self.run = wandb.init(project=os.environ.get("WANDB_PROJECT") or WANDB_PROJECT, name=name, id=run_id,
                              resume="allow", dir=str(run_dir), config=config, mode=self.mode,
                              settings=wandb.Settings(console="off", silent=True))
        self.dir = Path(self.run.dir).parent
        """This W&B run's folder (`<run_dir>/wandb/offline-run-...` offline): what `wandb sync` takes."""

    def scalars(self, metrics: dict[str, float], step: int) -> None:
        self.run.log(dict(metrics), step=step)

    def close(self) -> None:
        self.run.finish()


def open_sink(name: str, run_dir: Path, run_name: str = "", config: Any = None) -> ScalarSink:
    """The backend `name` (a `--logger` value) writing under `run_dir`; `config`, a dataclass,
    is attached to a W&B run."""
    check_logger(name)
    if name == "wandb":
        return WandbSink(run_dir, run_name or run_dir.name,
                         dataclasses.asdict(config) if dataclasses.is_dataclass(config) else dict(config or {}))
    return TensorBoardSink(run_dir)
