"""Training on several ranks (torch.distributed): one process per device, gradients averaged every step.

Each rank trains the same model on its own data (a stream shards by rank; a reservoir run gives every rank its
own ``datasets.ranks.RankReservoirStream``, fed with disjoint samples), and after each backward pass the ranks
average their gradients (``average_gradients``: one all-reduce of all gradients flattened, with the loss and
the example count), so every rank takes the same optimizer step and the weights stay equal, bit for bit. Rank 0
writes the run's files; every rank's data state goes into its checkpoint (``datasets.ranks.RankStates``), and a
run resumes only with the same world size.

Why not ``DistributedDataParallel``: its reducer refuses a model called several times with gradients in one
step (solver-in-the-loop unrolls the correction), and needs attribute forwarding for ``model.ndim``; one
explicit all-reduce per step works for every training mode and is bit for bit what DDP computes (the mean of
the ranks' gradients). What it gives up is DDP's overlap of communication with the backward pass.

Launch: ``pdestream train ... --ddp N`` (spawns N ranks here, rendezvous through a file), or torchrun, which sets
RANK / WORLD_SIZE / LOCAL_RANK / MASTER_ADDR / MASTER_PORT: ``torchrun --no-python --nproc-per-node N pdestream
train ...``. Backend: gloo on the CPU, nccl on CUDA (rank r on cuda:LOCAL_RANK).
"""

from __future__ import annotations

import datetime
import os

import torch
from torch import nn

from pdestream.datasets.normalize import Normalization
from pdestream.datasets.ranks import placement

from . import config

INIT_ENV = "PDESTREAM_DDP_INIT"  # our launcher's rendezvous (a file:// URL); torchrun's env:// otherwise
# a rank that died leaves the others waiting this long at most; rank 0 alone builds the test set at the end
TIMEOUT = datetime.timedelta(minutes=30)


def world() -> tuple[int, int]:
    """(rank, world_size) of this process: torch.distributed's when initialized, else (0, 1)."""
    return placement()


env_world = config.env_world  # the world size torchrun (or surrogate.launch) gave this process; 1 when not set


def init_from_env(device: str = "cpu") -> int:
    """Join the process group that the environment describes (RANK, WORLD_SIZE, and MASTER_ADDR/PORT or our
    launcher's file) with gloo (CPU) or nccl (``device`` cuda); returns the world size (1: nothing to join)."""
    dist = torch.distributed
    if dist.is_available() and dist.is_initialized():
        return dist.get_world_size()
    size = env_world()
    if size == 1:
        return 1
    rank, local = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", os.environ["RANK"]))
    backend = "nccl" if torch.device(device).type == "cuda" else "gloo"
    if backend == "nccl":
        torch.cuda.set_device(local)  # nccl's collectives (and all_gather_object) use the current device
    dist.init_process_group(backend, init_method=os.environ.get(INIT_ENV, "env://"), rank=rank, world_size=size,
                            timeout=TIMEOUT)
    return size


def finish() -> None:
    """Leave the process group (when one was joined)."""
    dist = torch.distributed
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def rank_device(device: str) -> str:
    """The device this rank trains on: ``device``, except that "cuda" under several ranks means cuda:LOCAL_RANK."""
    if world()[1] > 1 and device == "cuda":
        return f"cuda:{int(os.environ.get('LOCAL_RANK', world()[0]))}"
    return device


def barrier() -> None:
    """Wait for every rank (nothing in one process)."""
    if world()[1] > 1:
        torch.distributed.barrier()


def broadcast_model(model: nn.Module) -> None:
    """Rank 0's parameters and buffers on every rank (ranks seed alike, but a user's model may not)."""
    if world()[1] > 1:
        for t in [*model.parameters(), *model.buffers()]:
            torch.distributed.broadcast(t.data, src=0)


def agree(normalizer: Normalization | None) -> Normalization:
    """Rank 0's normalization on every rank; ValueError when the data source offers none (each rank would
    calibrate on its own first batch, and the ranks would train different models)."""
    if world()[1] == 1:
        return normalizer
    box = [None if normalizer is None else normalizer.to_dict()]
    torch.distributed.broadcast_object_list(box, src=0)
    if box[0] is None:
        raise ValueError("training on several ranks needs a data source with its own normalization "
                         "(a stream, a reservoir or a cache)")
    return Normalization.from_dict(box[0])


def average_gradients(model: nn.Module, loss: torch.Tensor, examples: int) -> tuple[float, int]:
    """Replace every gradient by its mean over the ranks; returns (mean loss, examples summed over the ranks).

    One all-reduce of one flat buffer [n_params + 2] (gradients, loss, example count): every rank then takes the
    same step, and all see the same loss, so a divergence stops them all. In one process: (loss, examples).
    """
    if world()[1] == 1:
        return loss.item(), examples
    params = [p for p in model.parameters() if p.requires_grad]
    grads = [(p.grad if p.grad is not None else torch.zeros_like(p)).reshape(-1) for p in params]
    extra = torch.tensor([loss.item(), float(examples)], dtype=grads[0].dtype, device=grads[0].device)
    flat = torch.cat([*grads, extra])
    torch.distributed.all_reduce(flat)
    flat /= world()[1]
    at = 0
    for p in params:
        n = p.numel()
        p.grad = flat[at:at + n].view_as(p).clone() if p.grad is None else p.grad.copy_(flat[at:at + n].view_as(p))
        at += n
    return flat[-2].item(), round(flat[-1].item() * world()[1])


def union(values: set) -> set:
    """The union of every rank's set (``values`` in one process)."""
    if world()[1] == 1:
        return values
    everyone = [None] * world()[1]
    torch.distributed.all_gather_object(everyone, sorted(values))
    return set().union(*everyone)
