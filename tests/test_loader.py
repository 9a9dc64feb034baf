"""The streaming loader: exact coverage across workers and ranks, determinism, resume."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from smspace.lake.dataset import Dataset
from smspace.lake.normalise import normalisers
from smspace.train.loader import TransitionStream

from .conftest import SAMPLES

DATASET = SAMPLES / "grid-seed0-MEM"


def normalised_rows() -> np.ndarray:
    ds = Dataset(DATASET)
    tr = ds.read_all()
    m_norm, s_norm = normalisers(ds.manifest)
    return np.hstack([m_norm(tr.m_t), s_norm(tr.s_t), m_norm(tr.m_t1), s_norm(tr.s_t1)])


def rows_of(batches) -> np.ndarray:
    return np.vstack([torch.cat(b, dim=1).numpy() for b in batches])


def sort_rows(x: np.ndarray) -> np.ndarray:
    return x[np.lexsort(x.T[::-1])]


def test_one_epoch_over_two_workers_covers_every_transition_once():
    stream = TransitionStream(DATASET, batch_size=100, seed=5, epochs=1, window=1)
    got = rows_of(DataLoader(stream, batch_size=None, num_workers=2))
    expected = normalised_rows()
    assert got.shape == expected.shape == (4096, 14)
    np.testing.assert_array_equal(sort_rows(got), sort_rows(expected))


def test_two_ranks_times_two_workers_split_without_overlap():
    """The sample has 4 batch units: 2 ranks × 2 workers take one unit each."""
    parts = []
    for rank in range(2):
        stream = TransitionStream(DATASET, batch_size=64, seed=1, epochs=1, rank=rank, world_size=2)
        parts.append(rows_of(DataLoader(stream, batch_size=None, num_workers=2)))
    assert len(parts[0]) == len(parts[1]) == 2048
    np.testing.assert_array_equal(sort_rows(np.vstack(parts)), sort_rows(normalised_rows()))


def test_only_model_inputs_leave_the_loader_normalised():
    m_t, s_t, m_t1, s_t1 = next(iter(TransitionStream(DATASET, batch_size=4096, seed=0, epochs=1)))
    assert m_t.shape == (4096, 3) and s_t.shape == (4096, 4) and m_t1.shape == (4096, 3) and s_t1.shape == (4096, 4)
    for x in (m_t, s_t):
        assert x.dtype == torch.float32
        np.testing.assert_allclose(x.min(0).values.numpy(), -1, atol=1e-6)
        np.testing.assert_allclose(x.max(0).values.numpy(), 1, atol=1e-6)


def take(stream, n: int) -> list[tuple[torch.Tensor, ...]]:
    it = iter(stream)
    return [next(it) for _ in range(n)]


def test_same_seed_same_stream_other_seed_other_stream():
    a = rows_of(take(TransitionStream(DATASET, seed=3), 50))
    b = rows_of(take(TransitionStream(DATASET, seed=3), 50))
    c = rows_of(take(TransitionStream(DATASET, seed=4), 50))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    # endless: 50 batches of 100 cross the 4096-transition epoch boundary, and epochs reshuffle
    assert len(a) == 5000
    assert not np.array_equal(a[:904], a[4096:])


def test_a_dataset_kept_decoded_in_memory_streams_the_same_bytes(monkeypatch):
    """A small dataset is decoded once per stream and its units served from memory afterwards; the
    stream is exactly the one read from the shards each epoch (three epochs, windows of 2)."""
    from smspace.train import loader

    cached = TransitionStream(DATASET, seed=6, window=2)
    a = rows_of(take(cached, 130))
    assert cached._caching and len(cached._decoded) == len(cached.units)
    monkeypatch.setattr(loader, "CACHE_BYTES", 0)
    read_each_time = TransitionStream(DATASET, seed=6, window=2)
    b = rows_of(take(read_each_time, 130))
    assert not read_each_time._caching and not read_each_time._decoded
    np.testing.assert_array_equal(a, b)


def test_batches_are_named_and_leave_workers_as_one_buffer_of_the_same_values():
    """A batch from a DataLoader worker is pickled as one buffer of bytes (not four shared-memory
    handles, which held workers to ~450 batches/s): the same values, names and shapes arrive."""
    import pickle

    from smspace.train.loader import Batch

    batch = next(iter(TransitionStream(DATASET, seed=4)))
    assert isinstance(batch, Batch) and batch.m_t.shape == (100, 3) and batch.s_t1.shape == (100, 4)
    back = pickle.loads(pickle.dumps(batch))
    assert isinstance(back, Batch) and all(torch.equal(a, b) for a, b in zip(batch, back, strict=True))
    back.m_t.add_(1)  # the arrived tensors are the receiver's own, writable
    via_workers = take(DataLoader(TransitionStream(DATASET, seed=4, window=1), batch_size=None, num_workers=2), 6)
    assert all(isinstance(b, Batch) for b in via_workers)
    for worker in (0, 1):  # worker w is consumer w of 2, as a rank of two would be
        alone = take(TransitionStream(DATASET, seed=4, window=1, rank=worker, world_size=2), 3)
        np.testing.assert_array_equal(rows_of(via_workers[worker::2]), rows_of(alone))


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_worker_batches_deal_many_batches_per_item_in_the_dataloaders_own_order(workers):
    """worker_batches sends 64 batches per queue item and deals them out as a DataLoader would,
    batch by batch: the same stream, its short last batches and uneven workers included, and the
    same continuation on resume."""
    from smspace.train.worker_batches import worker_batches

    for kw in (dict(seed=3, window=2, epochs=2), dict(seed=5, window=1, epochs=1, batch_size=77)):
        by_dataloader = list(DataLoader(TransitionStream(DATASET, **kw), batch_size=None, num_workers=workers))
        dealt = list(worker_batches(TransitionStream(DATASET, **kw), workers))
        assert [len(b[0]) for b in dealt] == [len(b[0]) for b in by_dataloader]
        np.testing.assert_array_equal(rows_of(dealt), rows_of(by_dataloader))
    resumed = [TransitionStream(DATASET, seed=2, window=1) for _ in range(2)]
    for stream in resumed:
        stream.load_state_dict({"seed": 2, "batch_size": 100, "batches_consumed": 13})
    by_dataloader = take(DataLoader(resumed[0], batch_size=None, num_workers=workers), 70)
    np.testing.assert_array_equal(rows_of(take(worker_batches(resumed[1], workers), 70)), rows_of(by_dataloader))


def test_resume_continues_the_exact_stream():
    full = rows_of(take(TransitionStream(DATASET, seed=9, window=2), 120))
    first = TransitionStream(DATASET, seed=9, window=2)
    head = rows_of(take(first, 47))
    state = first.state_dict()
    assert state["batches_consumed"] == 47
    resumed = TransitionStream(DATASET, seed=9, window=2)
    resumed.load_state_dict(state)
    tail = rows_of(take(resumed, 73))
    np.testing.assert_array_equal(np.vstack([head, tail]), full)


def test_resume_with_dataloader_workers():
    def stream() -> TransitionStream:
        return TransitionStream(DATASET, seed=2, window=1)

    full = rows_of(take(DataLoader(stream(), batch_size=None, num_workers=2), 30))
    resumed = stream()
    resumed.load_state_dict({"seed": 2, "batch_size": 100, "batches_consumed": 13})
    tail = rows_of(take(DataLoader(resumed, batch_size=None, num_workers=2), 17))
    np.testing.assert_array_equal(tail, full[1300:])


@pytest.mark.parametrize("workers", [0, 2])
def test_a_loop_of_ones_own_resumes_exactly_through_a_stateful_dataloader(workers):
    """The documented way (docs/API.md): checkpoint torchdata's StatefulDataLoader, which collects
    each worker's own stream state. Read in the main process, the stream's state_dict() knows
    nothing of what workers delivered; the loader's does."""
    from torchdata.stateful_dataloader import StatefulDataLoader

    def loader() -> StatefulDataLoader:
        return StatefulDataLoader(TransitionStream(DATASET, seed=2, window=1), batch_size=None, num_workers=workers)

    full = rows_of(take(loader(), 30))
    first = loader()
    it = iter(first)
    head = rows_of([next(it) for _ in range(13)])
    state = first.state_dict()
    del it
    resumed = loader()
    resumed.load_state_dict(state)
    tail = rows_of(take(resumed, 17))
    np.testing.assert_array_equal(np.vstack([head, tail]), full)


def test_a_worker_state_refuses_another_number_of_consumers():
    stream = TransitionStream(DATASET, seed=2, window=1)
    stream.load_state_dict(
        {"seed": 2, "batch_size": 100, "batches_consumed": 0, "consumer": {"index": 0, "count": 3, "delivered": 4}}
    )
    with pytest.raises(ValueError, match="3 consumers resumed by 2"):
        take(DataLoader(stream, batch_size=None, num_workers=2), 1)


def _rank_rows(rank: int, world: int, port: int, out: str) -> None:
    """One rank of a gloo group: a stream built without rank arguments, read by 2 spawn workers."""
    torch.distributed.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{port}", rank=rank, world_size=world)
    try:
        stream = TransitionStream(DATASET, batch_size=64, seed=1, epochs=1)
        loader = DataLoader(stream, batch_size=None, num_workers=2, multiprocessing_context="spawn")
        np.save(f"{out}/rank{rank}.npy", rows_of(loader))
    finally:
        torch.distributed.destroy_process_group()


def test_ranks_of_a_process_group_with_spawn_workers_read_each_unit_once(tmp_path, monkeypatch):
    """The rank comes from torch.distributed when the stream is built, not inside the workers (which,
    spawned, have no process group and used to read the whole dataset on every rank)."""
    from tests.servers import free_port

    monkeypatch.setenv("GLOO_SOCKET_IFNAME", "lo")
    torch.multiprocessing.spawn(_rank_rows, args=(2, free_port(), str(tmp_path)), nprocs=2, join=True)
    parts = [np.load(tmp_path / f"rank{r}.npy") for r in range(2)]
    assert len(parts[0]) == len(parts[1]) == 2048
    np.testing.assert_array_equal(sort_rows(np.vstack(parts)), sort_rows(normalised_rows()))
