"""`morphmimic bench capacity` measures every figure on a tiny configuration (the reach task, two
narrow widths, one block each) and writes them; the bytes per step are the encoded unroll's."""

from __future__ import annotations

import json
import math

import numpy as np

from common import wire
from learner.bench import capacity


def _figures(preset: dict) -> dict[str, float]:
    """Every measured figure of one preset, by name."""
    out = {"simulation us/step": preset["simulation"]["us_per_step"],
           "bytes/step": preset["transport"]["bytes_per_step"],
           "decode us/step": preset["transport"]["decode_us_per_step"],
           "round trip us": preset["round_trip_us"]}
    for row in preset["widths"]:
        w = row["width"]
        out |= {f"{w}: inference at {b}": us for b, us in row["inference_us_per_sample"].items()}
        out |= {f"{w}: update us/sample": row["update"]["us_per_sample"],
                f"{w}: minibatch step us": row["update"]["minibatch_step_us"],
                f"{w}: all-reduce us": row["allreduce_us"],
                f"{w}: actors one learner serves": row["actors_one_learner_serves"]}
    return out


def test_capacity_bench_measures_every_figure_and_writes_them(tmp_path, capsys):
    assert capacity.main(["--presets", "reach", "--widths", "16,32", "--repeats", "1", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "capacity.json").read_text())
    assert data["cpus"] >= 1 and data["torch"]
    (preset,) = data["presets"]
    assert preset["preset"] == "reach" and [r["width"] for r in preset["widths"]] == [16, 32]
    T, N = preset["unroll_length"], preset["envs_per_actor"]
    for row in preset["widths"]:
        assert list(row["inference_us_per_sample"]) == [str(b) for b in sorted({N, 64, 256, 1024})]
        assert row["update"]["updates_timed"] == 1 and row["update"]["minibatch_steps"] > 0
    figures = _figures(preset)
    bad = {name: v for name, v in figures.items() if not (math.isfinite(v) and v > 0)}
    assert not bad, bad
    # A wider net holds more parameters: the all-reduce measured the right sizes.
    assert preset["widths"][0]["trained_parameters"] < preset["widths"][1]["trained_parameters"]

    # Bytes per step: an unroll of this shape, encoded independently of the bench (zeros, not random values).
    o, a, p = preset["obs_dim"], preset["act_dim"], preset["n_params"]
    f32, flags = np.zeros((T, N), np.float32), np.zeros((T, N), bool)
    msg = wire.UnrollMsg(actor_id=0, seq=0, policy_version=0, obs=np.zeros((T, N, o), np.float32),
                         next_obs=np.zeros((T, N, o), np.float32), actions=np.zeros((T, N, a), np.float32), logp=f32,
                         rewards=f32, terminated=flags, truncated=flags, params=np.zeros((T, N, p), np.float32))
    assert figures["bytes/step"] == sum(len(f) for f in wire.encode(msg)) / (T * N)

    out = capsys.readouterr().out
    assert "actors served" in out and "inference round trip" in out
    md = (tmp_path / "capacity.md").read_text()
    assert "## reach" in md and md.count("\n| 16 |") == 1 and md.count("\n| 32 |") == 1
