"""SamplerActor as a real Ray actor on a private one-CPU local instance."""

import pytest

from common.params import ParamSpace
from learner.cluster import loopback_only
from sampler.actor import SamplerActor
from sampler.client import SamplerClient
from sampler.config import SamplerConfig

ray = pytest.importorskip("ray")


def test_sampler_actor_serves_draws_and_stops():
    with loopback_only():  # every server of the instance on 127.0.0.1
        ray.init(address="local", num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        space = ParamSpace(names=("steer", "speed"), low=(-1.0, 0.5), high=(1.0, 2.0))
        handle = ray.remote(num_cpus=0)(SamplerActor).remote(SamplerConfig(n_mcmc=100, seed=1), space, None)
        endpoint = ray.get(handle.endpoint.remote(), timeout=60)
        assert endpoint.startswith("tcp://127.0.0.1:")
        client = SamplerClient(lambda: endpoint, timeout_s=5.0)
        draws = client.draw(6)
        assert draws.params.shape == (6, 2) and draws.clip_ids == []
        assert client.stats()["draws/served"] == 6
        ray.get(handle.stop.remote(), timeout=30)
        assert ray.get(handle.alive.remote(), timeout=30) is False
        client.close()
    finally:
        ray.shutdown()
