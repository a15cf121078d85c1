"""`morphmimic bench env-steps` times this tree against a git revision, single and batched
environments against a pure physics loop, and says whether both compute the same
trajectories; the environment's hand-written cross product is `np.cross` bit for bit."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from common.tasks.executor.observations import _cross
from learner.bench import env_steps


def test_cross_is_numpys_bit_for_bit() -> None:
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(50, 3)) * 10.0 ** rng.integers(-8, 8, (50, 1)), rng.normal(size=(50, 3))
    assert np.array_equal(_cross(a, b), np.cross(a, b))


def _in_a_git_checkout() -> bool:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=env_steps.ROOT, capture_output=True, check=False).returncode == 0
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not _in_a_git_checkout(), reason="needs a git checkout with a HEAD commit")
def test_against_head_finds_the_same_trajectory(capsys: pytest.CaptureFixture[str]) -> None:
    assert env_steps.main(["--against", "HEAD", "--presets", "executor", "--steps", "40", "--rounds", "1",
                           "--episode-steps", "10"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("executor ")]
    step, this, other = rows  # the trees' steps; then each tree's against its physics loop
    assert step[-1] == "yes", rows
    assert int(step[4]) >= 4  # restarted at least every 10 steps: the resets were timed too
    assert this[1] == "this" and this[-1] == "yes" and other[1] == "other", rows  # the batch as its environments alone
    assert float(this[2]) > 0 and float(this[4]) == pytest.approx(float(this[3]) / float(this[2]), rel=0.02)  # printed rounded


def test_a_trajectory_digest_changes_with_the_actions() -> None:
    first = env_steps.time_presets(["executor"], 20, seed=0)["executor"]["digest"]
    assert env_steps.time_presets(["executor"], 20, seed=0)["executor"]["digest"] == first
    assert env_steps.time_presets(["executor"], 20, seed=1)["executor"]["digest"] != first
    short = env_steps.time_presets(["executor"], 20, seed=0, episode_steps=5)["executor"]
    assert short["resets"] >= 4 and short["reset_ms"] > 0 and short["digest"] != first


@pytest.mark.skipif(not _in_a_git_checkout(), reason="needs a git checkout with a HEAD commit")
@pytest.mark.parametrize("argv, says", [
    (["--against", "no-such-revision"], "is not a commit"),
    (["--against", "HEAD", "--presets", "nope"], "unknown nope"),
    (["--against", "HEAD", "--steps", "0"], "--steps"),
])
def test_bad_arguments_are_named(argv: list[str], says: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        env_steps.main(argv)
    assert exit_info.value.code == 2
    assert says in capsys.readouterr().err
