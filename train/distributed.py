"""One run on several processes: PyTorch DDP under torchrun (gloo on CPUs, nccl on GPUs).

torchrun sets RANK, WORLD_SIZE, MASTER_ADDR and MASTER_PORT; `smtrain fit` then joins the process
group, each rank streams its own share of the units (the loader splits them by rank), DDP
averages the gradients, and rank 0 alone evaluates, writes metrics and checkpoints. --batch-size
stays the global batch (the paper's 100): each rank takes batch_size / world_size.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import torch
import torch.distributed as dist

from smspace.common.errors import SmspaceError, one_line


@dataclass(frozen=True)
class Ranks:
    rank: int = 0
    world: int = 1

    @property
    def primary(self) -> bool:
        """The rank that owns the run folder: creates it, evaluates, writes, prints."""
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world > 1


SINGLE = Ranks()


STORE_ENV = "SMSPACE_DDP_STORE"  # host:port of the store `launch_local` hosts for its ranks
INTERRUPTED = 130  # a rank's exit code when Ctrl-C or SIGTERM stopped it (its launcher says so, once)
PEER_LOST = 3  # a rank's exit code when it only lost contact with another one (launch_local names the cause)


class PeerLost(SmspaceError):
    """Another rank of the run stopped (killed, failed): this one cannot go on alone."""

    exit_code = 1


class RankFailed(SmspaceError):
    """A rank's own error (out of memory, a model's bug): its cause, in one line."""

    exit_code = 1


# what gloo, nccl and the store say when the other end of a collective is gone
PEER_GONE = ("connection closed by peer", "connection reset by peer", "broken pipe", "connection refused",
             "timed out", "timeout", "socket", "read error", "write error", "process group", "peer")  # fmt: skip


def lost_a_peer(e: BaseException) -> bool:
    """Whether an error of a collective says another rank is gone, rather than this rank failed."""
    if isinstance(e, dist.DistError):  # DistNetworkError, DistBackendError, DistStoreError
        return True
    return any(words in str(e).lower() for words in PEER_GONE)


@contextmanager
def peer_errors(ranks: Ranks) -> Iterator[None]:
    """A collective that fails because another rank is gone (gloo: connection closed or reset)
    becomes PeerLost; any other error of this rank (out of memory, a plugin model's shape error)
    is one line with its cause, never called a lost peer. Either way, not a backend traceback."""
    try:
        yield
    except SmspaceError:
        raise
    except (RuntimeError, dist.DistError) as e:
        if not ranks.distributed:
            raise
        first = one_line(e, limit=160)
        if not lost_a_peer(e):
            raise RankFailed(
                f"rank {ranks.rank} failed: {one_line(e, limit=300, with_type=True)}; the run keeps its last checkpoint"
            ) from e
        raise PeerLost(
            f"rank {ranks.rank} lost another rank of this run ({first}); the run keeps its last checkpoint"
        ) from None


def join_from_environment(device: str) -> Ranks:
    """The process group described in the environment (by torchrun, or by `launch_local`), joined;
    one process otherwise."""
    world = int(os.environ.get("WORLD_SIZE", "1") or 1)
    if world <= 1:
        return SINGLE
    if not dist.is_initialized():
        backend = "nccl" if device.startswith("cuda") else "gloo"
        try:
            hosted = os.environ.get(STORE_ENV)
            if hosted:  # a client of the store our launcher listens with, on 127.0.0.1 only
                host, port = hosted.rsplit(":", 1)
                store = dist.TCPStore(host, int(port), world, is_master=False, use_libuv=False)
                dist.init_process_group(backend, store=store, rank=int(os.environ["RANK"]), world_size=world)
            else:
                dist.init_process_group(backend)
        except Exception as e:
            raise SmspaceError(f"cannot join the torchrun process group ({backend}): {one_line(e)}") from None
    if device.startswith("cuda"):
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))
    return Ranks(dist.get_rank(), dist.get_world_size())


def leave(ranks: Ranks) -> None:
    if ranks.distributed and dist.is_initialized():
        dist.destroy_process_group()


def per_rank_batch(batch_size: int, ranks: Ranks) -> int:
    if batch_size % ranks.world:
        raise SmspaceError(
            f"--batch-size {batch_size} is the global batch and must divide evenly over {ranks.world} ranks"
        )
    return batch_size // ranks.world


def mean_over_ranks(losses: torch.Tensor, ranks: Ranks) -> torch.Tensor:
    """The global mean loss, the same on every rank: a NaN on any rank stops all of them together."""
    if not ranks.distributed:
        return losses
    total = losses.detach().clone()
    dist.all_reduce(total)
    return total / ranks.world


def ranks_agree(model: torch.nn.Module, ranks: Ranks) -> bool:
    """Whether every rank holds bit-identical weights (a hash of all parameters, gathered)."""
    if not ranks.distributed:
        return True
    h = hashlib.sha256()
    for tensor in model.state_dict().values():
        h.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    device = next(model.parameters()).device  # nccl gathers GPU tensors only
    mine = torch.tensor(list(h.digest()[:8]), dtype=torch.int64, device=device)
    gathered = [torch.zeros_like(mine) for _ in range(ranks.world)]
    dist.all_gather(gathered, mine)
    return all(torch.equal(g, gathered[0]) for g in gathered)


def all_ok(ok: bool, ranks: Ranks) -> bool:
    """Whether every rank got through a step that only some ranks perform (rank 0 creating the
    run folder): a rank that failed must not leave the others waiting in a collective forever."""
    if not ranks.distributed:
        return ok
    flag = torch.tensor([1 if ok else 0], dtype=torch.int64)
    if dist.get_backend() == "nccl":
        flag = flag.cuda()
    dist.all_reduce(flag, op=dist.ReduceOp.MIN)
    return bool(flag.item())
