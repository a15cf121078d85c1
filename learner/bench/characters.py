"""`morphmimic bench characters`: what a character costs, per preset, in one table.

Columns: build+compile time of a new random shape (F applied to a fresh base, then compiled:
`load_character`), the same through a `CharacterFactory` that keeps the base (what an
environment pays per episode) and the ratio of the two, standing-pose solve time, on-the-fly shape change (`morph`: F in place + `MjSpec.recompile` +
lift), and simulation cost per 30 Hz control step under zero and uniform random PD targets
(physics at the characters' default step unless --timestep is given).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from common.config_limits import SEED, Limit, above, at_least, check_limits, validated
from learner.cli_options import CommaStrs, parse_options


@validated
@dataclass
class CharacterBenchOptions:
    presets: CommaStrs = ()
    """Comma-separated presets or mjcf:<path> (default: every preset)."""
    shapes: int = 10
    """Random shapes per preset."""
    control_steps: int = 150
    """30 Hz control steps timed per action mode."""
    timestep: float | None = None
    """Physics step [s] (default: the preset's)."""
    seed: int = 0
    """Seed of the random shapes and actions."""

    LIMITS: ClassVar[dict[str, Limit]] = {"shapes": at_least(1), "control_steps": at_least(1),
                                          "timestep": above(0), "seed": SEED}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def _ms(fn, n: int) -> float:
    t = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t) / n * 1e3


def bench_preset(preset: str, n_shapes: int, n_control: int, timestep_s: float | None, seed: int) -> dict:
    import mujoco  # lazy: start-up time of morphmimic bench characters --help (mujoco)

    # lazy: start-up time of morphmimic bench characters --help (mujoco, scipy)
    from common.characters import CharacterFactory, load_character, morph

    rng = np.random.default_rng(seed)
    space = load_character(preset, timestep_s=timestep_s).space
    shapes = [space.sample(rng) for _ in range(n_shapes)]
    it = iter(shapes * 2)
    build_ms = _ms(lambda: load_character(preset, next(it), timestep_s=timestep_s), n_shapes)
    factory = CharacterFactory(preset, timestep_s=timestep_s)
    it = iter(shapes * 2)
    factory_ms = _ms(lambda: factory.make(next(it)), n_shapes)
    chars = [load_character(preset, s, timestep_s=timestep_s) for s in shapes]
    it_c = iter(chars)
    pose_ms = _ms(lambda: next(it_c).standing_qpos, n_shapes)
    ch = chars[0]
    data = ch.make_data()
    state = {"ch": ch, "data": data}
    it_m = iter(shapes[1:] + shapes[:1])

    def change() -> None:
        state["ch"], state["data"] = morph(state["ch"], next(it_m), state["data"])

    morph_ms = _ms(change, n_shapes)
    ch = load_character(preset, shapes[0], timestep_s=timestep_s)
    m = ch.model
    substeps = max(1, int(round(1.0 / 30.0 / m.opt.timestep)))
    lo, hi = m.actuator_ctrlrange.T
    out = {"preset": preset, "build_ms": build_ms, "factory_ms": factory_ms, "pose_ms": pose_ms, "morph_ms": morph_ms, "substeps": substeps,
           "dt_ms": m.opt.timestep * 1e3}
    for mode in ("zero", "random"):
        d = ch.make_data()

        def step() -> None:
            d.ctrl[:] = rng.uniform(lo, hi) if mode == "random" else 0.0
            for _ in range(substeps):
                mujoco.mj_step(m, d)

        out[f"{mode}_ms"] = _ms(step, n_control)
    return out


def main(argv: list[str]) -> int:
    # lazy: start-up time of morphmimic bench characters --help (mujoco, scipy)
    from common.characters import list_presets

    args = parse_options(CharacterBenchOptions, argv, prog="morphmimic bench characters",
                         description=__doc__.split("\n\n")[0])
    header = (f"{'preset':<12} {'build+compile':>13} {'factory':>8} {'ratio':>5} {'pose solve':>10} {'morph':>8} {'dt':>7} {'substeps':>8} "
              f"{'ctrl step zero':>14} {'ctrl step rand':>14} {'ctrl steps/s':>12}")
    print(header)
    print("-" * len(header))
    for preset in args.presets or list_presets():
        r = bench_preset(preset, args.shapes, args.control_steps, args.timestep, args.seed)
        print(f"{preset:<12} {r['build_ms']:>10.1f} ms {r['factory_ms']:>5.1f} ms {r['build_ms'] / r['factory_ms']:>5.1f} {r['pose_ms']:>7.1f} ms {r['morph_ms']:>5.1f} ms "
              f"{r['dt_ms']:>4.2f}ms {r['substeps']:>8d} {r['zero_ms']:>11.2f} ms {r['random_ms']:>11.2f} ms "
              f"{1e3 / r['random_ms']:>12.0f}")
    return 0
