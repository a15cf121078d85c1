"""Per-iteration progress: one block on the console, the same lines in `log.txt`, and every
metric as a scalar of the chosen `--logger` backend (`learner.scalar_sinks`: TensorBoard by
default, or W&B; namespaces `charts/`, `losses/`, `stats/`, `wire/`, `sampler/`)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from learner.scalar_sinks import ScalarSink, TensorBoardSink, WandbSink


def _fmt_duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    seconds = int(seconds)
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s"


class RunLog:
    def __init__(self, run_dir: Path, quiet: bool = False, sink: ScalarSink | None = None):
        """`sink`: where the scalars go (`learner.scalar_sinks.open_sink`); None: TensorBoard."""
        self.file = open(run_dir / "log.txt", "a", buffering=1)
        self.sink = sink if sink is not None else TensorBoardSink(run_dir)
        self.quiet = quiet
        if isinstance(self.sink, WandbSink):
            self.line(f"[morphmimic] W&B run ({self.sink.mode}) in {self.sink.dir}"
                      + (f"; upload it with `wandb sync {self.sink.dir}`" if self.sink.mode == "offline" else ""))

    def line(self, text: str) -> None:
        self.file.write(text + "\n")
        if not self.quiet:
            print(text, file=sys.stdout, flush=True)

    def iteration(self, it: int, env_steps: int, budget: int, steps_per_s: float, eta_s: float, metrics: dict[str, float]) -> None:
        self.sink.scalars({name: value for name, value in metrics.items()
                           if isinstance(value, (int, float)) and math.isfinite(value)}, env_steps)
        get = lambda k: metrics.get(k, float("nan"))  # noqa: E731
        self.line(
            f"iter {it:5d} | steps {env_steps:>10,d}/{budget:,d} | {steps_per_s:7.0f} steps/s | "
            f"return {get('charts/episode_return'):8.3f} | length {get('charts/episode_length'):6.1f} | "
            f"eta {_fmt_duration(eta_s)}"
        )
        self.line(
            f"           policy {get('losses/policy'):+.4f} value {get('losses/value'):.4f} "
            f"entropy {get('losses/entropy'):.3f} kl {get('losses/kl'):.4f} lr {get('losses/lr'):.2e} | "
            f"lag-dropped {int(get('wire/stale_unrolls'))} gaps {int(get('wire/seq_gap_unrolls'))} "
            f"rejected {int(get('wire/rejected'))} divergences {int(get('stats/divergences'))} | "
            f"learner {100 * get('stats/learner_share'):.0f}%"
        )
        sampler = {k: v for k, v in metrics.items() if k.startswith("sampler/")}
        if sampler:
            keys = [k for k in ("sampler/buffer/generation", "sampler/mcmc/acceptance", "sampler/mcmc/refill_s",
                                "sampler/vm/vbar", "sampler/vm/min", "sampler/vm/max", "sampler/draws/served",
                                "sampler/clips/tracked_pct", "sampler/clips/p_min", "sampler/clips/p_max") if k in sampler]
            self.line("           sampler " + " ".join(f"{k[8:]} {sampler[k]:.4g}" for k in keys))

    def close(self) -> None:
        self.sink.close()
        self.file.close()
