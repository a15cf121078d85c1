"""Checkpoints: atomic, last N kept, loadable with weights_only=True, corrupt ones skipped."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learner import checkpoint


def _state(i: int) -> dict:
    return {"iteration": i, "weights": torch.full((3,), float(i)), "sampler": checkpoint.to_checkpointable({"buffer": np.ones((2, 2))})}


def test_keeps_last_n_and_loads_weights_only(tmp_path):
    for i in range(1, 6):
        checkpoint.save(tmp_path, i, _state(i), keep=3)
    assert [p.name for p in checkpoint.list_checkpoints(tmp_path)] == ["00000003", "00000004", "00000005"]
    raw = torch.load(tmp_path / "00000005" / "state.pt", weights_only=True)
    assert raw["iteration"] == 5
    back = checkpoint.from_checkpointable(raw["sampler"])
    assert isinstance(back["buffer"], np.ndarray)


def test_corrupt_latest_falls_back_to_previous(tmp_path, caplog):
    for i in (1, 2):
        checkpoint.save(tmp_path, i, _state(i), keep=3)
    latest = tmp_path / "00000002" / "state.pt"
    latest.write_bytes(latest.read_bytes()[:50])  # truncated, as by a full disk
    path, state = checkpoint.load_latest(tmp_path)
    assert path.name == "00000001" and state["iteration"] == 1
    assert "cannot be read" in caplog.text
    with pytest.raises(checkpoint.CheckpointError, match="00000002"):
        checkpoint.load(tmp_path / "00000002")


def test_unfinished_write_is_invisible(tmp_path):
    checkpoint.save(tmp_path, 1, _state(1), keep=3)
    (tmp_path / ".tmp-00000002-123").mkdir()  # what a SIGKILL mid-write leaves
    (tmp_path / ".tmp-00000002-123" / "state.pt").write_bytes(b"partial")
    assert [p.name for p in checkpoint.list_checkpoints(tmp_path)] == ["00000001"]
    assert checkpoint.load_latest(tmp_path)[1]["iteration"] == 1


def test_foreign_file_gets_a_clear_error(tmp_path):
    (tmp_path / "x.pt").write_text("not a checkpoint")
    with pytest.raises(checkpoint.CheckpointError, match="x.pt"):
        checkpoint.load(tmp_path / "x.pt")


def test_learner_state_brings_back_the_stream_that_picks_value_pairs(tmp_path):
    """Through a real checkpoint file (weights_only): a resumed learner picks the same (shape,
    V) pairs for the sampler as the one that kept running."""
    import dataclasses

    from learner.learner import Learner
    from learner.presets import PRESETS

    cfg = dataclasses.replace(PRESETS["lower_biped-tiny"][1], name="tiny")
    a = Learner(cfg)
    a.rng.integers(0, 100, size=17)  # the stream has moved on
    checkpoint.save(tmp_path, 1, a.state_dict(), keep=1)
    b = Learner(dataclasses.replace(cfg, seed=cfg.seed + 1))
    b.load_state_dict(torch.load(tmp_path / "00000001" / "state.pt", weights_only=True))
    np.testing.assert_array_equal(a.rng.choice(4096, 512, replace=False), b.rng.choice(4096, 512, replace=False))
