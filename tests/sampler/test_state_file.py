"""The sampler service keeps its own state file (issue 54, item 4): saved on its schedule and on
stop, restored by a service started again on the same folder, and a damaged file is refused
with a log line rather than served. Real services on 127.0.0.1, each on its own thread."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from common.params import ParamSpace
from sampler import state_file
from sampler.actor import start_in_thread
from sampler.client import SamplerClient
from sampler.config import SamplerConfig

SPACE = ParamSpace(names=("leg", "arm"), low=(0.5, 0.5), high=(2.0, 1.5))
CFG = SamplerConfig(p_mcmc=2, n_mcmc=200, n_chains=16, burn_in=20, vm_fit_steps=20, probe_points=128, seed=3)


def _serve(cfg: SamplerConfig):
    svc, thread, stop = start_in_thread(cfg, SPACE)
    return svc, thread, stop, SamplerClient(svc.endpoint, timeout_s=5.0, retries=1)


def _stop(client: SamplerClient, stop, thread) -> None:
    client.close()
    stop.set()
    thread.join(timeout=10)


def _report(client: SamplerClient, n: int, iteration: int) -> dict:
    rng = np.random.default_rng(iteration)
    client.report(SPACE.uniform(rng, n), rng.normal(size=n))
    return client.tick(iteration)


def test_a_stopped_service_saves_and_a_new_one_restores_it(tmp_path):
    cfg = dataclasses.replace(CFG, state_dir=str(tmp_path))
    svc, thread, stop, client = _serve(cfg)
    for it in range(1, 4):
        stats = _report(client, 64, it)
    _stop(client, stop, thread)
    assert (tmp_path / state_file.FILE).is_file() and svc.saves >= 1
    again, thread2, stop2, client2 = _serve(cfg)
    try:
        back = client2.stats()
    finally:
        _stop(client2, stop2, thread2)
    assert back["state/restored"] == 1 and stats["state/restored"] == 0
    assert back["vm/pairs_taken"] == stats["vm/pairs_taken"] == 3 * 64
    assert back["buffer/generation"] == stats["buffer/generation"] >= 1
    assert back["state/started_unix_s"] > stats["state/started_unix_s"]


def test_the_file_is_saved_on_the_schedule_while_serving(tmp_path):
    cfg = dataclasses.replace(CFG, state_dir=str(tmp_path), state_every_s=0.2)
    svc, thread, stop, client = _serve(cfg)
    try:
        _report(client, 32, 1)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not (tmp_path / state_file.FILE).is_file():
            time.sleep(0.05)
        saved = state_file.load(tmp_path)
    finally:
        _stop(client, stop, thread)
    assert saved is not None and saved["meta"]["pairs_taken"] == 32


def test_a_damaged_file_is_refused_and_the_service_starts_empty(tmp_path, caplog):
    (tmp_path / state_file.FILE).write_bytes(b"PK\x03\x04 not really a zip")
    svc, thread, stop, client = _serve(dataclasses.replace(CFG, state_dir=str(tmp_path)))
    try:
        stats = client.stats()
    finally:
        _stop(client, stop, thread)
    assert stats["state/restored"] == 0 and stats["vm/pairs_taken"] == 0
    assert "cannot be read" in caplog.text
