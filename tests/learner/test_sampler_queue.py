"""Value pairs the sampler cannot take are kept (bounded) and delivered later, or counted lost
(issue 54, item 4): a real sampler service on 127.0.0.1 is stopped and started again at the
same address while the learner's handle keeps reporting."""

from __future__ import annotations

import numpy as np

from common.params import ParamSpace
from learner.sampler_handle import MAX_UNSENT_PAIRS, SamplerHandle
from sampler.actor import start_in_thread
from sampler.config import SamplerConfig

SPACE = ParamSpace(names=("leg", "arm"), low=(0.5, 0.5), high=(2.0, 1.5))
CFG = SamplerConfig(p_mcmc=50, n_mcmc=100, n_chains=4, burn_in=5, vm_fit_steps=2, probe_points=16, seed=3,
                    max_pending_pairs=4 * MAX_UNSENT_PAIRS)


def _pairs(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return SPACE.uniform(rng, n).astype(np.float32), rng.normal(size=n).astype(np.float32)


def test_pairs_wait_for_a_sampler_that_is_down_and_overflow_is_counted():
    handle = SamplerHandle.start(CFG, SPACE, [], None)
    patience = handle.client.rpc.timeout_ms, handle.client.rpc.retries
    handle.client.rpc.timeout_ms, handle.client.rpc.retries = 300, 1  # a quick outage; restored once it is back
    endpoint = handle.endpoint
    try:
        handle.report_and_tick(*_pairs(100, 1), iteration=1)
        assert handle.pairs_delivered == 100 and handle.taken_expected == 100
        handle.stop_event.set()  # the service goes away
        handle.thread.join(timeout=10)
        for it, n in ((2, 200), (3, MAX_UNSENT_PAIRS - 100)):
            handle.down_until = 0.0  # NOTE: skip the circuit breaker's pause: each call tries the socket
            out = handle.report_and_tick(*_pairs(n, it), iteration=it)
            assert out["sampler/learner_call_failures"] >= 1
        assert handle.unsent_pairs() == 200 + MAX_UNSENT_PAIRS - 100 - 200  # the oldest report was dropped
        assert handle.pairs_lost == 200
        _, thread, stop = start_in_thread(CFG, SPACE, address=endpoint)  # back, empty, where clients look
        handle.thread, handle.stop_event = thread, stop
        handle.client.rpc.timeout_ms, handle.client.rpc.retries = patience
        handle.down_until = 0.0
        handle.report_and_tick(*_pairs(50, 4), iteration=4)
        stats = handle.client.stats()
    finally:
        handle.stop()
    assert handle.unsent_pairs() == 0
    delivered = 100 + (MAX_UNSENT_PAIRS - 100) + 50
    assert handle.pairs_delivered == delivered
    # The restarted sampler lost the first 100 (it began empty): counted, so every pair is accounted.
    assert stats["vm/pairs_taken"] == delivered - 100 and handle.pairs_lost == 200 + 100
    assert handle.counters()["faults/value_pairs_lost"] == 300 and handle.restarts == 1
