"""Which torch device a process puts its networks on (`--learner.device`, `--sampler.device`)."""

from __future__ import annotations

import torch


def resolve(name: str) -> torch.device:
    """cpu, cuda or auto (cuda when this process sees a GPU, else cpu). ValueError naming the
    value when cuda is asked for and there is none, so the run stops before it starts."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"--learner.device cuda: this process sees no CUDA GPU (torch {torch.__version__}, "
                         "torch.cuda.is_available() is False); give cpu, or auto to use a GPU only where there is one")
    if name not in ("cpu", "cuda"):
        raise ValueError(f"--learner.device {name!r}: give cpu, cuda or auto")
    return torch.device(name)
