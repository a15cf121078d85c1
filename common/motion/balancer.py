"""The motion balancer (UniCon 2020, Sec. 5.1, Eq. 8): draw clips by walking a class tree.

Clip labels are paths (`root/locomotion/walk/forward/style/zombie`). They form a tree; a draw
starts at the top and picks each child with probability 1 / |C(v)| until it reaches clips, so a
class with one clip weighs as much as a sibling class with a hundred. As the paper notes, every
clip's probability can be computed once for the dataset: a draw samples that exact distribution,
which is the same as walking the tree and costs one vectorized `rng.choice`.

Two cases the paper does not spell out, handled so that probabilities stay exact:
- several clips with the same label share their leaf uniformly (e.g. the same walk from two
  mocap sources);
- clips whose label is an inner node (`.../walk/forward` while `.../walk/forward/style/zombie`
  also exists) form one extra child of that node, named `.`, beside its sub-classes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from fractions import Fraction
from importlib import resources
from pathlib import Path
from typing import Sequence

import numpy as np

HERE = "."
"""Name of the pseudo-child holding the clips labelled with an inner node itself."""


@dataclass
class _Node:
    children: dict[str, "_Node"] = field(default_factory=dict)
    clips: list[str] = field(default_factory=list)


def default_clips_path() -> Path:
    """The repository's clip list (`common/data/clips.json`, shipped as package data)."""
    return Path(str(resources.files("common") / "data" / "clips.json"))


def load_clip_labels(path: str | Path | None = None) -> list[tuple[str, str]]:
    """`[(clip_id, label), ...]` from a clips.json (`{"clips": [{"id", "label", ...}]}`)."""
    path = Path(path) if path is not None else default_clips_path()
    doc = json.loads(path.read_text())
    try:
        return [(str(c["id"]), str(c["label"])) for c in doc["clips"]]
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{path}: expected {{'clips': [{{'id': ..., 'label': ...}}]}} ({exc!r} missing)") from None


class MotionBalancer:
    """Per-clip probabilities from label paths, and vectorized draws of clip ids."""

    def __init__(self, clips: Sequence[tuple[str, str]]):
        if not clips:
            raise ValueError("MotionBalancer needs at least one (clip_id, label) pair")
        ids = [cid for cid, _ in clips]
        dupes = sorted({c for c in ids if ids.count(c) > 1})
        if dupes:
            raise ValueError(f"clip ids repeat: {dupes}; each clip needs a unique id")
        top = _Node()
        for cid, label in clips:
            parts = [p for p in label.strip("/").split("/") if p]
            if not parts or HERE in parts:
                raise ValueError(f"clip {cid!r} has label {label!r}; use a path like root/locomotion/walk")
            node = top
            for part in parts:
                node = node.children.setdefault(part, _Node())
            node.clips.append(cid)
        self.clip_ids: tuple[str, ...] = tuple(ids)
        exact: dict[str, Fraction] = {}
        self._walk(top, Fraction(1), exact)
        self.exact_probabilities: dict[str, Fraction] = {cid: exact[cid] for cid in ids}
        """Clip id -> exact probability (a Fraction); sums to 1."""
        self.probabilities: np.ndarray = np.array([float(exact[c]) for c in ids])
        """`[n_clips]` float64, in `clip_ids` order."""
        self.probabilities /= self.probabilities.sum()  # exact in Fractions; renormalize float rounding
        self.draw_probabilities: np.ndarray = self.probabilities.copy()
        """What `draw` samples: `probabilities` times the factors of `set_factors` (adaptive clip
        sampling, `sampler/clip_outcomes.py`), renormalized; equal to them until factors are set."""

    @classmethod
    def from_clips_json(cls, path: str | Path | None = None) -> "MotionBalancer":
        return cls(load_clip_labels(path))

    @classmethod
    def with_probabilities(cls, clip_ids: Sequence[str], probabilities: np.ndarray) -> "MotionBalancer":
        """A balancer over `clip_ids` with these probabilities, used as given (no class tree;
        `exact_probabilities` is empty; a repeated id is drawn through each of its entries)."""
        self = cls.__new__(cls)
        self.clip_ids = tuple(clip_ids)
        self.exact_probabilities = {}
        self.probabilities = np.asarray(probabilities, dtype=np.float64).reshape(-1).copy()
        self.draw_probabilities = self.probabilities.copy()
        return self

    def _walk(self, node: _Node, p: Fraction, out: dict[str, Fraction]) -> None:
        branches: list[tuple[str, _Node | None]] = [(name, child) for name, child in node.children.items()]
        if node.clips:
            branches.append((HERE, None))
        share = p / len(branches)
        for _, child in branches:
            if child is None:
                for cid in node.clips:
                    out[cid] = share / len(node.clips)
            else:
                self._walk(child, share, out)

    def set_factors(self, factors: np.ndarray) -> None:
        """Draw clip c with probability proportional to `probabilities[c] * factors[c]`
        (`clip_ids` order; positive and finite)."""
        f = np.asarray(factors, dtype=np.float64).reshape(-1)
        if f.shape != self.probabilities.shape or not (np.isfinite(f).all() and (f > 0).all()):
            raise ValueError(f"clip factors of shape {f.shape}; expected {self.probabilities.shape}, positive and finite")
        p = self.probabilities * f
        self.draw_probabilities = p / p.sum()

    def draw(self, rng: np.random.Generator, n: int) -> list[str]:
        """`n` clip ids drawn independently from `draw_probabilities` (the balanced distribution,
        reweighted by `set_factors` if it was called)."""
        idx = rng.choice(len(self.clip_ids), size=n, p=self.draw_probabilities)
        return [self.clip_ids[i] for i in idx]

    def table(self) -> str:
        """The per-clip probabilities, one `clip_id  p` line per clip, most likely first."""
        order = np.argsort(-self.probabilities, kind="stable")
        width = max(len(c) for c in self.clip_ids)
        return "\n".join(f"{self.clip_ids[i]:<{width}}  {self.probabilities[i]:.4f}" for i in order)
