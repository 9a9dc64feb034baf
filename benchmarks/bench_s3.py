"""Training-loader speed from object storage versus a local folder: the same grid dataset in a
local lake and on a local S3 server (moto, 127.0.0.1), streamed by TransitionStream.

Prints one JSON object: transitions/s for each, and for S3 the HTTP requests and bytes per 1000
transitions (counted on the client: every request s3fs sends, and the body bytes of its GETs).
The moto server runs on this machine, so the figures measure our request pattern, not a network.
Usage: python benchmarks/bench_s3.py [--transitions 65536] [--batch-size 64] [--epochs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from smspace.datagen.generate import generate
from smspace.lake.dataset import Dataset
from smspace.lake.store import open_store
from smspace.train.loader import TransitionStream
from tests.servers import moto_s3


def stream_rate(ds: Dataset, batch_size: int, epochs: int) -> tuple[float, int]:
    stream = TransitionStream(ds, batch_size, seed=0, epochs=epochs, rank=0, world_size=1)
    n, t0 = 0, time.perf_counter()
    for batch in stream:
        n += len(batch[0])
    return n / (time.perf_counter() - t0), n


class RequestCounter:
    """Counts the requests (and response bytes) an s3fs client sends, via botocore's events."""

    def __init__(self, fs) -> None:
        self.requests, self.bytes = 0, 0
        fs.connect()
        fs.s3.meta.events.register("before-send.s3", self._sent)
        fs.s3.meta.events.register("after-call.s3", self._received)

    def _sent(self, **_) -> None:
        self.requests += 1

    def _received(self, http_response=None, model=None, **_) -> None:
        if getattr(model, "name", "") != "GetObject":  # a HEAD's content-length is the object's, not sent
            return
        length = getattr(http_response, "headers", {}).get("content-length") if http_response is not None else None
        self.bytes += int(length or 0)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--transitions", type=int, default=65536)
    ap.add_argument("--batch-size", type=int, default=64)
    ap.add_argument("--epochs", type=int, default=2)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp, moto_s3(Path(tmp) / "moto.log") as env:
        os.environ.update(env)
        local_lake, s3_lake = Path(tmp) / "lake", open_store("s3://lake/bench")
        for lake in (local_lake, s3_lake):
            generate(lake, "grid", ["MME"], [0], args.transitions, 32768, workers=1)
        local = Dataset.open("grid-seed0-MME", local_lake)
        remote = Dataset.open("grid-seed0-MME", s3_lake)
        local_rate, n = stream_rate(local, args.batch_size, args.epochs)
        counter = RequestCounter(remote.store.fs)
        remote_rate, _ = stream_rate(remote, args.batch_size, args.epochs)
        shard_bytes = sum(s["bytes"] for s in remote.manifest.shards)
    print(
        json.dumps(
            {
                "benchmark": "s3_loader",
                "transitions": args.transitions,
                "streamed_transitions": n,
                "shards": len(remote.manifest.shards),
                "batch_size": args.batch_size,
                "local_transitions_per_s": round(local_rate),
                "s3_transitions_per_s": round(remote_rate),
                "s3_requests": counter.requests,
                "s3_requests_per_1000_transitions": round(1000 * counter.requests / n, 3),
                "s3_bytes_per_transition": round(counter.bytes / n, 1),
                "stored_bytes_per_transition": round(shard_bytes / args.transitions, 1),
                "cpu_count": os.cpu_count(),
            }
        )
    )


if __name__ == "__main__":
    main()
