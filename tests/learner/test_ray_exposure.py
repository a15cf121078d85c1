"""Ray exposes nothing that need not be: a learner's private local instance listens on loopback
only and dies with the learner, SIGKILL included; the KubeRay manifest serves the dashboard
inside the head pod only unless asked. A real learner process (`--mode local`) and `ss`."""

from __future__ import annotations

import ipaddress
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from tests.learner.processes import alive, descendants

ROOT = Path(__file__).resolve().parents[2]
LEAVE_S = 10.0
"""How long a Ray process may outlive a SIGKILLed learner (main: 60-75 s)."""


def _listening(pids: set[int]) -> list[tuple[str, int, str]]:
    """(address, pid, process name) of every listening TCP socket of `pids`."""
    out = subprocess.run(["ss", "-ltnpH"], capture_output=True, text=True, timeout=30, check=True).stdout
    found = []
    for line in out.splitlines():
        owners = [(int(p), n) for n, p in re.findall(r'\("([^"]*)",pid=(\d+)', line)]
        local = line.split()[3]
        found += [(local, pid, name) for pid, name in owners if pid in pids]
    return found


def _read_until(proc: subprocess.Popen, start: str, timeout_s: float = 180.0) -> list[str]:
    """The process's output lines up to the first that starts with `start` (or its end)."""
    lines, deadline = [], time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        lines.append(line)
        if line.startswith(start) or (not line and proc.poll() is not None):
            break
    return lines


def _loopback(local: str) -> bool:
    host = local.rsplit(":", 1)[0].strip("[]")
    if host.startswith("::ffff:"):
        host = host[7:]
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@pytest.mark.skipif(shutil.which("ss") is None or not Path("/proc/self/stat").exists(), reason="needs ss and /proc")
def test_a_local_run_listens_on_loopback_only_and_nothing_of_ray_outlives_a_killed_learner(tmp_path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    args = [sys.executable, "-m", "learner.main", "--preset", "reach-tiny", "--mode", "local", "--runs-dir", str(tmp_path),
            "--total-env-steps", "1000000000", "--checkpoint-every", "1000"]
    proc = subprocess.Popen(args, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    seen = {}
    try:
        lines = _read_until(proc, "iter     1")
        assert any(line.startswith("iter     1") for line in lines), "".join(lines[-30:])
        seen = descendants(proc.pid)
        names = alive(seen)
        assert any("gcs_server" in n for n in names.values()) and any("raylet" in n for n in names.values()), names
        sockets = _listening({proc.pid, *seen})
        assert len(sockets) >= 4, sockets  # GCS, raylet, workers, the learner's own
        exposed = [s for s in sockets if not _loopback(s[0])]
        assert not exposed, f"listening beyond loopback: {exposed}"
        assert "nodes ['127.0.0.1']" in "".join(lines)

        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        end = time.monotonic() + LEAVE_S
        while alive(seen) and time.monotonic() < end:
            time.sleep(0.2)
        assert not alive(seen), f"still running {LEAVE_S:g} s after the learner's SIGKILL: {alive(seen)}"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
        for pid in alive(seen):  # only this test's own processes, by pid
            os.kill(pid, signal.SIGKILL)


def test_the_kuberay_head_serves_the_dashboard_inside_its_pod_only() -> None:
    manifest = yaml.safe_load((ROOT / "deploy/kuberay.yaml").read_text())
    head = manifest["spec"]["headGroupSpec"]
    # KubeRay sets dashboard-host 0.0.0.0 when the manifest says nothing: it must say 127.0.0.1
    assert head["rayStartParams"].get("dashboard-host") == "127.0.0.1"
    ports = [p for c in head["template"]["spec"]["containers"] for p in c.get("ports", [])]
    assert 8265 not in {p["containerPort"] for p in ports}


@pytest.mark.skipif(shutil.which("ss") is None or not Path("/proc/self/stat").exists(), reason="needs ss and /proc")
def test_the_local_test_cluster_listens_on_loopback_only() -> None:
    """`morphmimic local-cluster`: a head and two workers, each node at 127.0.0.1 and every
    server of theirs bound to loopback (before: GCS, raylets and agents on all interfaces)."""
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    proc = subprocess.Popen([sys.executable, "-m", "learner.cli", "local-cluster"], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    seen = {}
    try:
        lines = _read_until(proc, "stop it:")
        assert any("test cluster up" in line for line in lines), "".join(lines[-30:])
        assert "at 127.0.0.1:" in "".join(lines)
        seen = descendants(proc.pid)
        names = alive(seen)
        assert sum("raylet" in n for n in names.values()) == 3, names  # head + 2 workers
        sockets = _listening({proc.pid, *seen})
        assert len(sockets) >= 6, sockets
        exposed = [s for s in sockets if not _loopback(s[0])]
        assert not exposed, f"listening beyond loopback: {exposed}"
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=30)
        for pid in alive(seen):
            os.kill(pid, signal.SIGKILL)
