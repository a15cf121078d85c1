"""Every registered task as a Gymnasium environment (`common.tasks.gym`): Gymnasium's own
checker passes on each, the action box is where the task clips, `reset` options set the shape
or the clip, and the README's loop runs as written."""

from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from common.tasks.executor.presets import executor_task
from common.tasks.gym import ENV_IDS, env_id
from common.tasks.registry import TASKS
from common.tasks.shape.presets import shape_task

ROOT = Path(__file__).resolve().parents[3]


def test_every_registered_task_has_an_id() -> None:
    assert ENV_IDS == [env_id(task) for task in TASKS]
    assert env_id("lower_biped") == "morphmimic/LowerBiped-v0" and env_id("executor") == "morphmimic/Executor-v0"
    assert set(ENV_IDS) <= set(gymnasium.registry)


@pytest.mark.render
@pytest.mark.parametrize("task", list(TASKS))
def test_check_env_passes(task: str) -> None:
    env = gymnasium.make(env_id(task), render_mode="rgb_array")
    inner = env.unwrapped
    assert env.observation_space.shape == (inner.env.obs_dim,) and env.action_space.shape == (inner.env.act_dim,)
    check_env(inner)  # spaces, reset seeding and options, step determinism, render, close
    obs, _ = env.reset(seed=0)
    frame = env.render()
    assert obs in env.observation_space
    assert frame.shape == (480, 480, 3) and frame.dtype == np.uint8 and frame.std() > 1.0
    env.close()


@pytest.mark.parametrize("task", list(TASKS))
def test_actions_outside_the_box_act_as_its_edge(task: str) -> None:
    """The action space is honest: the task clips at its bounds, not before or after."""
    env = gymnasium.make(env_id(task))
    high = env.action_space.high.astype(np.float64)
    after = {}
    for scale in (0.5, 1.0, 10.0):
        env.reset(seed=4)
        after[scale] = env.step(scale * high)[0]
    assert np.array_equal(after[1.0], after[10.0])
    assert not np.array_equal(after[0.5], after[1.0])


def test_reset_options_set_the_shape_and_the_clip() -> None:
    env = gymnasium.make("morphmimic/LowerBiped-v0").unwrapped
    env.reset(seed=0, options={"shape": {"global_z": 1.1}})
    names = env.param_space.names
    assert env.env.params[names.index("global_z")] == pytest.approx(1.1)
    assert env.env.params[names.index("global_x")] == pytest.approx(env.param_space.default_array[names.index("global_x")])
    vector = env.param_space.low_array
    env.reset(seed=0, options={"params": vector})
    assert np.allclose(env.env.params, vector)
    drawn = [env.reset(seed=s)[0] for s in (1, 2)]
    assert not np.array_equal(*drawn), "without options each episode draws its shape"
    with pytest.raises(ValueError, match="global_z"):
        env.reset(options={"shape": {"global_z": 99.0}})
    with pytest.raises(ValueError, match="allowed"):
        env.reset(options={"shpae": {}})

    ex = gymnasium.make("morphmimic/Executor-v0").unwrapped
    for clip in ("humanoid3d_walk", "humanoid3d_kick"):
        _, info = ex.reset(seed=0, options={"clip_id": clip, "start_s": 0.5})
        assert info["clip_id"] == clip
    with pytest.raises(ValueError, match="humanoid3d_run"):  # held out: not in the train split
        ex.reset(options={"clip_id": "humanoid3d_run"})
    held_out = dataclasses.replace(executor_task(), executor=dataclasses.replace(executor_task().executor, split="test"))
    _, info = gymnasium.make("morphmimic/Executor-v0", config=held_out).reset(options={"clip_id": "humanoid3d_run"})
    assert info["clip_id"] == "humanoid3d_run"
    with pytest.raises(ValueError, match="start_s"):
        env.reset(options={"start_s": 0.5})


def test_config_override() -> None:
    pd = gymnasium.make("morphmimic/Executor-v0", config=executor_task("pd"))
    assert pd.unwrapped.cfg.executor.actuation == "pd" and pd.action_space.high[0] == 3.0
    assert gymnasium.make("morphmimic/Executor-v0").unwrapped.cfg.executor.actuation == "torque"
    assert gymnasium.make("morphmimic/Biped-v0").unwrapped.cfg == shape_task("biped")
    with pytest.raises(ValueError, match="not 'fish'"):
        gymnasium.make("morphmimic/Fish-v0", config=shape_task("manta"))


def test_the_id_names_the_module_without_an_import() -> None:
    """Gymnasium 1.x loads no plugin entry points; `module:id` makes it import the module."""
    code = "import gymnasium; e = gymnasium.make('common.tasks.gym:morphmimic/Reach-v0'); print(e.reset(seed=0)[0].shape)"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "(12,)"


@pytest.mark.render
def test_readme_loop_runs() -> None:
    blocks = re.findall(r"\n\n((?:    .*\n)+)", (ROOT / "README.md").read_text())  # indented code blocks
    loop = [textwrap.dedent(b) for b in blocks if b.lstrip().startswith("import gymnasium")]
    assert len(loop) == 1, "the README shows one Gymnasium loop"
    scope: dict = {}
    exec(compile(loop[0], "README.md", "exec"), scope)
    assert scope["frame"].shape == (480, 480, 3)


@pytest.mark.parametrize("options, says", [
    ({"params": "x"}, "reset option 'params' = 'x'"),
    ({"params": [0.1, 9.0]}, "out of range"),
    ({"clip_id": 3}, "reset option 'clip_id' = 3"),
    ({"start_s": 1.0}, "reset option 'start_s'"),
])
def test_bad_reset_options_name_the_option_and_what_is_allowed(options, says) -> None:
    env = gymnasium.make("morphmimic/Reach-v0")
    with pytest.raises(ValueError, match=re.escape(says)):
        env.reset(seed=0, options=options)
