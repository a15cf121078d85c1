"""Test helper: whether a Ray rollout actor killed by the test came back as a new process."""

from __future__ import annotations


def restarted_pid(handle, killed_pid: int) -> int | None:
    """The actor's pid when it answers from a process other than `killed_pid`, else None
    (still restarting, or the old process)."""
    import ray  # lazy: heavy (ray), only the Ray-mode tests call it

    try:
        pid = ray.get(handle.stats.remote(), timeout=1.0)["pid"]
    except ray.exceptions.RayError:
        return None
    return pid if pid != killed_pid else None
