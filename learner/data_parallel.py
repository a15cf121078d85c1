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


def backend(device: torch.device) -> str:
    """nccl between GPUs, gloo between CPU processes."""
    return "nccl" if device.type == "cuda" else "gloo"


def free_port(host: str) -> int:
    """A TCP port free on `host` now (the rendezvous port of the process group)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def loopback_env(host: str) -> dict[str, str]:
    """Environment that keeps gloo's own connections on loopback when the group's rendezvous is
    127.0.0.1 (gloo otherwise binds the interface of this machine's hostname)."""
    return {"GLOO_SOCKET_IFNAME": "lo"} if host == "127.0.0.1" else {}


def join(init_method: str, rank: int, world: int, device: torch.device, timeout_s: float) -> None:
    """Join the data-parallel process group (blocks until all `world` replicas have joined)."""
    host = init_method.removeprefix("tcp://").rpartition(":")[0]
    os.environ.update(loopback_env(host))
    dist.init_process_group(backend(device), init_method=init_method, rank=rank, world_size=world,
                            timeout=datetime.timedelta(seconds=timeout_s))


def leave() -> None:
    if dist.is_initialized():
        dist.destroy_process_group()
