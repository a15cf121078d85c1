"""What `morphmimic bench soak` prints at the end: load held, faults survived, unrolls lost
(counted and uncounted), the counters other work adds (read by name when present), and the final
return against a clean run of the same length. Pure arithmetic on the learners' status files
(soak_learner.py) and the soak's own record; returns whether every goal was met.

Loss accounting. Ground truth is the actors' durable sequence ledgers (`actors/seq_ledger.py`):
every unroll an actor numbered was received by the learner, or counted as a sequence gap, or
still in flight at the stop, or counted under `lost/*` (work lost at a resume: counters by that
name, where the learner has them). Every received unroll was trained on, dropped as stale,
or left unused: at the stop, or waiting for a batch in a session killed after its checkpoint
(`unused_at_resume`). What these identities do not explain is "uncounted"; a negative figure
means the learner booked more than the actors ever numbered: forged counters accepted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

GOALS = {"stall_s": 30.0, "return_within": 0.10}
"""The project's goal for a 10-minute soak: no stall longer than 30 s, return within 10% of clean."""


@dataclass
class SoakRecord:
    """What the soak itself saw, beside the learners' status files."""

    minutes: float
    wall_s: float = 0.0
    """Wall time of the faulted run, learner restarts included."""
    segments: list[dict] = field(default_factory=list)
    """The last status of each learner process, in order (the last one final)."""
    outside: list[dict] = field(default_factory=list)
    """Faults injected from outside: {"kind", "at", "outcome"}."""
    longest_stall_s: float = 0.0
    not_injected: list[str] = field(default_factory=list)
    """Outside faults the soak ended before (it injects them only into a learner that iterates)."""
    clean: dict | None = None
    """The clean run's final status and its wall time (`wall_s`), or None (not run, or it did not finish)."""


def _sum(d: dict, prefix: str) -> dict[str, float]:
    return {k: v for k, v in d.items() if k.startswith(prefix)}


def accounting(final: dict) -> dict[str, float]:
    c = final.get("counters", {})
    metrics = final.get("metrics", {})
    numbered = sum(final.get("ledger", {}).values())
    last_seq = final.get("last_seq", {})
    in_flight = sum(n - 1 - last_seq.get(a, -1) for a, n in final.get("ledger", {}).items())
    lost_named = _sum({**metrics, **{f"lost/{k[5:]}": v for k, v in c.items() if k.startswith("lost/")}}, "lost/")
    received = c.get("unrolls_received", 0)
    gaps, stale, trained = (c.get(k, 0) for k in ("seq_gap_unrolls", "stale_unrolls", "unrolls_trained"))
    at_stop, at_resume = c.get("unused_at_stop", 0), c.get("unused_at_resume", 0)
    unused = at_stop + at_resume
    return {
        "numbered": numbered, "received": received, "trained": trained, "gaps": gaps, "stale": stale, "unused": unused,
        "unused_at_stop": at_stop, "unused_at_resume": at_resume,
        "in_flight": in_flight, "lost_named": sum(lost_named.values()),
        "uncounted_wire": numbered - received - gaps - in_flight - sum(lost_named.values()),
        "uncounted_learner": received - trained - stale - unused,
    }


def report(rec: SoakRecord, out=print) -> bool:
    """Print the report; True when every goal held."""
    segs = [s for s in rec.segments if s]
    if not segs:
        out("soak: no learner iteration completed; nothing to report")
        return False
    final = segs[-1]
    ok = True
    out(f"\nsoak: {rec.wall_s / 60:.1f} min, {len(segs)} learner process(es), {final['iteration']} iterations, "
        f"{final['env_steps']:,d} env steps")

    rate = final["env_steps"] / max(rec.wall_s, 1e-9)
    clean_rate = rec.clean["env_steps"] / max(rec.clean["wall_s"], 1e-9) if rec.clean else None
    held = f" (clean run {clean_rate:,.0f}/s: {rate / clean_rate:.0%})" if clean_rate else ""
    out(f"load held:        {rate:,.0f} env steps/s under faults{held}; longest stall {rec.longest_stall_s:.1f} s "
        f"(goal <= {GOALS['stall_s']:g} s)")
    ok &= rec.longest_stall_s <= GOALS["stall_s"]

    faults = [f for s in segs for f in s.get("faults", [])] + rec.outside
    kinds: dict[str, list[str]] = {}
    for f in faults:
        kinds.setdefault(f["kind"], []).append(f["outcome"])
    survived = sum(o == "survived" for f in faults for o in [f["outcome"]])
    out(f"faults injected:  {len(faults)}  " + ", ".join(f"{k} {len(v)}" for k, v in sorted(kinds.items())))
    out(f"faults survived:  {survived}/{len(faults)}")
    for f in faults:
        if f["outcome"] != "survived":
            out(f"    {f['kind']}: {f['outcome']}")
    ok &= survived == len(faults)
    not_injected, why = {}, {}
    for s in segs:
        for k, v in s.get("not_injected", {}).items():
            not_injected[k] = not_injected.get(k, 0) + v
        why.update(s.get("why_not", {}))
    if not_injected:
        out(f"    not injected at first (target down; tried again): {not_injected}; last reasons {why}")
    if rec.not_injected:
        out(f"    not injected (the soak ended first): {', '.join(rec.not_injected)}")
        ok = False

    c, m = final.get("counters", {}), final.get("metrics", {})
    rejected = _sum(c, "rejected/")
    out(f"messages refused: {sum(rejected.values())} on the unroll channel {rejected} (the last learner's checkpointed counters)")
    weights: dict[str, float] = {}
    sampler: dict[str, float] = {}
    for s in segs:  # per-process counters (not checkpointed): summed over the learner processes
        for k, v in s.get("snapshot_replies_dropped", {}).items():
            weights[k] = weights.get(k, 0) + v
        for k, v in _sum(s.get("metrics", {}), "sampler/requests/replies_dropped/").items():
            key = k.rsplit("/", 1)[1]
            sampler[key] = sampler.get(key, 0) + int(v)
    out(f"slow readers:     replies dropped by the weights ROUTER {weights}, by the sampler's {sampler}")

    if "ledger" in final:
        a = accounting(final)
        counted = a["gaps"] + a["stale"] + a["unused"] + a["in_flight"] + a["lost_named"]
        out(f"unrolls:          numbered {a['numbered']:,d} by the actors, received {a['received']:,d}, "
            f"trained {a['trained']:,d}")
        out(f"losses counted:   {counted:,d} (gaps {a['gaps']:,d}, stale {a['stale']:,d}, unused at stop {a['unused_at_stop']:,d}, "
            f"unused by a killed session {a['unused_at_resume']:,d}, "
            f"in flight at stop {a['in_flight']:,d}, lost/* {a['lost_named']:,d}; "
            f"late arrivals {c.get('late_unrolls', 0):,d}, not gaps)")
        uncounted = a["uncounted_wire"] + a["uncounted_learner"]
        line = f"losses uncounted: {uncounted:,d} (wire {a['uncounted_wire']:,d}, learner {a['uncounted_learner']:,d})"
        if a["uncounted_wire"] < 0 or a["uncounted_learner"] < 0:
            line += "; negative: the learner booked more than the actors numbered (forged counters accepted)"
        out(line)
        ok &= a["uncounted_wire"] == 0 and a["uncounted_learner"] == 0
    else:
        out("losses:           the last learner did not stop cleanly; no final accounting")
        ok = False

    div, eps = final.get("learner_counters", {}).get("divergences", 0), final.get("episodes", 0)
    forged = div > max(eps, 0)
    out(f"bookkeeping:      divergences {div:,d} over {eps:,d} episodes" + (" (more than episodes: forged)" if forged else "")
        + f", sequence restarts {c.get('seq_restarts', 0):,d}")
    ok &= not forged
    counted = {**m, **{k if k.startswith("lost/") else f"wire/{k}": v for k, v in c.items()}}
    named = {p: _sum(counted, p) for p in ("wire/dropped_", "lost/")}
    named["faults/"] = _sum(m, "faults/")
    out("counters by name: " + "; ".join(f"{p}* {v if v else 'absent'}" for p, v in named.items()))

    ret = final.get("return", float("nan"))
    if rec.clean is not None:
        clean_ret = rec.clean.get("return", float("nan"))
        gap = abs(ret - clean_ret) / max(abs(clean_ret), 1e-9) if math.isfinite(ret) and math.isfinite(clean_ret) else float("inf")
        out(f"return:           {ret:.3f} under faults vs {clean_ret:.3f} clean at {rec.clean['env_steps']:,d} env steps "
            f"({gap:.1%} apart; goal within {GOALS['return_within']:.0%})")
        ok &= gap <= GOALS["return_within"]
    else:
        out(f"return:           {ret:.3f} under faults; no clean run to compare (--no-clean, or it did not finish)")
        ok = False
    out(f"soak verdict:     {'every goal held' if ok else 'goals missed (above)'}")
    return ok
