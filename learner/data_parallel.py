"""Data-parallel PPO: the part of `--learner.replicas N` that runs inside the update.

Every replica holds the same networks, optimizer state and minibatch generator and receives the
whole batch, so all of them draw the same minibatches in the same order. Each computes the
forward and backward pass of its own slice of every minibatch (`GradientSync.slice`), and one
`torch.distributed` all-reduce per step averages the gradients together with the KL, the loss
metrics and a finite-loss flag. Since the slices are equal, the average of the slices' mean-loss
gradients is the whole minibatch's gradient: each replica then takes the single learner's step,
and as the all-reduce hands every replica the same sums, their parameters stay equal.

The processes are started by `learner.replicas`; this module only needs an initialized default
process group (gloo on CPU, nccl on GPU).
"""

from __future__ import annotations

import datetime
import os
import socket
import uuid
from pathlib import Path

import torch
import torch.distributed as dist


class GradientSync:
    """One replica's view of the data-parallel group: its rank, the world size, and the
    all-reduce that makes every replica's step the same."""

    def __init__(self, rank: int, world: int):
        self.rank, self.world = rank, world

    def slice(self, minibatch: int) -> slice:
        """This replica's rows of a minibatch of `minibatch` rows (the config makes it divide evenly)."""
        size = minibatch // self.world
        return slice(self.rank * size, (self.rank + 1) * size)

    @torch.no_grad()
    def average_(self, params: list[torch.nn.Parameter], record: torch.Tensor,
                 finite: torch.Tensor) -> tuple[bool, torch.Tensor]:
        """Replace each gradient by its mean over the replicas, in one all-reduce that also
        averages `record` (this slice's loss metrics, KL among them). Returns (whether every
        replica's loss was finite, the averaged record). Parameters without a gradient (the
        policy's once it has stopped for this update: the same on every replica) are left out."""
        grads = [p.grad for p in params if p.grad is not None]
        flat = torch.cat([g.reshape(-1) for g in grads]
                         + [record.to(grads[0].dtype if grads else record.dtype),
                            finite.to(record.device, record.dtype).reshape(1)])
        dist.all_reduce(flat)
        flat.div_(self.world)
        offset = 0
        for g in grads:
            g.copy_(flat[offset : offset + g.numel()].view_as(g))
            offset += g.numel()
        averaged = flat[offset : offset + record.numel()].to(record.dtype)
        # NOTE: the flag is 1 on a replica with a finite loss: its mean is 1 only if all were.
        return bool(flat[-1] >= 1.0), averaged


    @torch.no_grad()
    def check_equal(self, tensors: list[torch.Tensor]) -> None:
        """Stop the run if the replicas' copies have drifted apart. They take the same steps, but
        each computes the pre-epoch passes (GAE values, PopArt and normalizer statistics) on its
        own copy: a node that computes differently (another CPU or GPU model, another thread
        count) would drift without this. One all-gather of a checksum per update."""
        mine = torch.stack([torch.stack([t.double().sum(), t.double().square().sum()]) for t in tensors]).sum(0)
        everyone = [torch.empty_like(mine) for _ in range(self.world)]
        dist.all_gather(everyone, mine)
        spread = (torch.stack(everyone) - mine).abs().max()
        if spread > 1e-9 * (1.0 + mine.abs().max()):
            raise RuntimeError(f"learner replicas diverged: parameter checksums {[x.tolist() for x in everyone]} "
                               f"(rank {self.rank}); their nodes compute differently: resume with --learner.replicas 1 "
                               "or on identical nodes")


def backend(device: torch.device) -> str:
    """nccl between GPUs, gloo between CPU processes."""
    return "nccl" if device.type == "cuda" else "gloo"


def rendezvous(host: str, directory: str | Path) -> str:
    """Where the group meets. On one machine (`host` 127.0.0.1) a file in `directory` (a FileStore:
    no socket at all); across machines a free TCP port on `host`, which the store listens on with
    every interface (torch's TCPStore binds no single address): firewall it, like Ray's own ports."""
    if host == "127.0.0.1":
        Path(directory).mkdir(parents=True, exist_ok=True)
        return f"file://{Path(directory).resolve()}/rendezvous-{uuid.uuid4().hex}"
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return f"tcp://{host}:{s.getsockname()[1]}"


def on_one_machine(init_method: str) -> bool:
    return init_method.startswith("file://") or init_method.startswith("tcp://127.0.0.1:")


LOOPBACK_ENV = {"GLOO_SOCKET_IFNAME": "lo"}
"""Keeps gloo's own connections between the replicas on loopback (it otherwise binds the
interface of this machine's hostname)."""


def join(init_method: str, rank: int, world: int, device: torch.device, timeout_s: float) -> None:
    """Join the data-parallel process group (blocks until all `world` replicas have joined)."""
    if on_one_machine(init_method):
        os.environ.update(LOOPBACK_ENV)
    dist.init_process_group(backend(device), init_method=init_method, rank=rank, world_size=world,
                            timeout=datetime.timedelta(seconds=timeout_s))


def leave() -> None:
    if dist.is_initialized():
        dist.destroy_process_group()
