"""The code tree carries shipped checkpoints only: every tracked `.pt` file stays under 10 MB and
all of them together under 40 MB (issue 50 item 6). Runs, ablation arms and in-progress
checkpoints belong in the ignored `runs/`, their records in `docs/experiments/`."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MB = 1024 * 1024
MAX_FILE = 10 * MB
MAX_TOTAL = 40 * MB


def _git(*args: str) -> subprocess.CompletedProcess:
    """`git -C ROOT args`; skips the test when git is missing or ROOT is not a git checkout."""
    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    inside = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--is-inside-work-tree"],
                            capture_output=True, text=True, timeout=60)
    if inside.returncode != 0 or inside.stdout.strip() != "true":
        pytest.skip(f"{ROOT} is not a git checkout")
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, timeout=60)


def tracked_sizes(pattern: str) -> dict[str, int]:
    """Tracked files matching `pattern` -> size in bytes (a file deleted from the work tree but
    still in the index counts as its staged blob)."""
    listed = _git("ls-files", "-z", "--", pattern)
    assert listed.returncode == 0, listed.stderr.decode(errors="replace")
    sizes = {}
    for name in filter(None, listed.stdout.decode().split("\0")):
        path = ROOT / name
        if path.is_file():
            sizes[name] = path.stat().st_size
        else:
            blob = _git("cat-file", "-s", f":{name}")
            sizes[name] = int(blob.stdout) if blob.returncode == 0 else 0
    return sizes


def size_problems(sizes: dict[str, int], max_file: int = MAX_FILE, max_total: int = MAX_TOTAL) -> list[str]:
    """What breaks the limits, naming the offenders, largest first; empty when nothing does."""
    ranked = sorted(sizes.items(), key=lambda kv: (-kv[1], kv[0]))
    problems = [f"{name} is {size / MB:.1f} MB (limit {max_file / MB:g} MB a file)"
                for name, size in ranked if size > max_file]
    total = sum(sizes.values())
    if total > max_total:
        problems.append(f"tracked .pt files add up to {total / MB:.1f} MB (limit {max_total / MB:g} MB): "
                        + ", ".join(f"{name} ({size / MB:.1f} MB)" for name, size in ranked))
    return problems


def test_tracked_checkpoints_stay_within_10_mb_each_and_40_mb_in_all() -> None:
    sizes = tracked_sizes("*.pt")
    assert sizes, "no tracked .pt file: the shipped checkpoints are missing"
    problems = size_problems(sizes)
    assert not problems, "\n".join(problems)


def test_the_check_names_each_offender() -> None:
    """The limits themselves, on made-up sizes: one file too large, then too many in all."""
    assert size_problems({"a/state.pt": 10 * MB, "b/state.pt": 9 * MB, "c/state.pt": 9 * MB, "d/state.pt": 9 * MB}) == []
    big = size_problems({"a/state.pt": 11 * MB, "b/state.pt": 2 * MB})
    assert len(big) == 1 and big[0].startswith("a/state.pt is 11.0 MB")
    many = size_problems({f"r{i}/state.pt": 7 * MB for i in range(6)})
    assert len(many) == 1 and "add up to 42.0 MB" in many[0] and all(f"r{i}/state.pt" in many[0] for i in range(6))


def test_the_runs_folder_is_ignored() -> None:
    """Training writes into `runs/` at the repository's root; it must never be committed."""
    ignored = _git("check-ignore", "-q", "runs/x/ckpt/00000001/state.pt")
    assert ignored.returncode == 0, "runs/ is not ignored by .gitignore"
