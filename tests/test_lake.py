"""Write/read round trip, determinism, resume, overwrite refusal, catalog and info."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from smspace.datagen.parts import shard_rng, world_for
from smspace.datagen.setups import draw_transitions
from smspace.lake.dataset import Dataset
from smspace.lake.manifest import GenConfig
from smspace.lake.shards import ShardReader
from smspace.lake.store import exists, open_store

from .conftest import BIN, smgen


def files_of(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*.mcap"))}


def test_round_trip_equals_the_generator(grid_lake):
    ds = Dataset.open("grid-seed3-MME", grid_lake)
    got = ds.read_all()
    cfg = GenConfig(**ds.manifest.config)
    world = world_for("grid", 3)
    lo, _ = cfg.shard_range(1)
    rng = shard_rng(cfg, 1)
    first = draw_transitions(world, "MME", rng, cfg.batch_size)
    for name in ("m_t", "m_t1", "s_t", "s_t1", "p_t", "p_t1", "shift_t", "shift_t1"):
        np.testing.assert_array_equal(getattr(got, name)[lo : lo + cfg.batch_size], getattr(first, name))
    assert len(got) == 6000 and got.s_t.dtype == np.float32


def test_manifest_statistics_and_regular_sampling(grid_lake):
    ds = Dataset.open(grid_lake / "grid-seed3-MM")
    tr = ds.read_all()
    norm = ds.manifest.normalisation
    np.testing.assert_array_equal(norm["m_min"], tr.m_t.min(0))
    np.testing.assert_array_equal(norm["s_max"], tr.s_t.max(0))
    m, p = ds.regular_sampling()
    assert m.shape == (125, 3) and p.shape == (125, 2)
    assert ds.manifest.regular_sampling["count"] == 125
    assert [s["transitions"] for s in ds.manifest.shards] == [2500, 2500, 1000]


def test_modes_share_the_world_and_validate(grid_lake):
    result = smgen("validate", "--lake", grid_lake, "grid-seed3-MEM", "grid-seed3-MM", "grid-seed3-MME")
    assert result.exit_code == 0, result.output
    assert result.output.count(": ok") == 3
    tables = []
    for mode in ("MEM", "MM", "MME"):
        tr = Dataset.open(f"grid-seed3-{mode}", grid_lake).read_all()
        world = world_for("grid", 3)
        np.testing.assert_array_equal(tr.s_t, world.sense(tr.p_t, tr.shift_t))
        tables.append(tr)
    assert np.all(tables[1].shift_t == 5)


def test_catalog_ls_and_info(grid_lake):
    table = pq.read_table(grid_lake / "catalog.parquet").to_pylist()
    assert sorted(r["id"] for r in table) == ["grid-seed3-MEM", "grid-seed3-MM", "grid-seed3-MME"]
    assert all(r["transitions"] == 6000 and r["sensor_shape"] == [4] for r in table)
    out = smgen("ls", "--lake", grid_lake)
    assert out.exit_code == 0 and "grid-seed3-MME" in out.output
    info = json.loads(smgen("info", "--lake", grid_lake, "grid-seed3-MM", "--json").output)
    for key, value in {
        "setup": "grid",
        "mode": "MM",
        "world_seed": 3,
        "transitions": 6000,
        "shards": 3,
        "schema_version": 1,
        "exploration": "transitions",
        "n_motor": 3,
        "sensor_shape": [4],
        "regular_sampling_size": 125,
    }.items():
        assert info[key] == value, key


def test_same_bytes_whatever_the_worker_count(tmp_path):
    args = ["--setup", "grid", "--mode", "MEM", "--transitions", 9000, "--shard-size", 2000, "--seed", 11]
    one = smgen("generate", *args, "--lake", tmp_path / "a", "--workers", 1)
    two = subprocess.run(
        [str(BIN / "smgen"), "generate", *map(str, args), "--lake", str(tmp_path / "b"), "--workers", "2"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert one.exit_code == 0 and two.returncode == 0, two.stderr
    a, b = tmp_path / "a" / "grid-seed11-MEM", tmp_path / "b" / "grid-seed11-MEM"
    assert files_of(a) == files_of(b) and len(files_of(a)) == 6
    assert (a / "manifest.json").read_bytes() == (b / "manifest.json").read_bytes()


def test_existing_dataset_with_another_config_is_refused(tmp_path):
    base = ["generate", "--setup", "grid", "--mode", "MM", "--seed", 2, "--lake", tmp_path]
    assert smgen(*base, "--transitions", 3000).exit_code == 0
    before = files_of(tmp_path / "grid-seed2-MM")
    again = smgen(*base, "--transitions", 3000)
    assert again.exit_code == 0 and "exists" in again.output
    refused = smgen(*base, "--transitions", 4000)
    assert refused.exit_code == 2 and "--overwrite" in refused.output
    assert files_of(tmp_path / "grid-seed2-MM") == before
    replaced = smgen(*base, "--transitions", 4000, "--overwrite")
    assert replaced.exit_code == 0
    assert Dataset.open("grid-seed2-MM", tmp_path).manifest.transitions == 4000


def test_killed_generation_resumes_to_identical_bytes(tmp_path):
    args = ["generate", "--setup", "grid", "--mode", "MME", "--transitions", 400_000, "--shard-size", 4096, "--seed", 4]
    killed_lake, clean_lake = tmp_path / "killed", tmp_path / "clean"
    folder = killed_lake / "grid-seed4-MME"
    proc = subprocess.Popen(
        [str(BIN / "smgen"), *map(str, args), "--lake", str(killed_lake)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 600
    while len(list(folder.glob("shard-*.mcap"))) < 5 and time.time() < deadline:
        time.sleep(0.005)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    survivors = sorted(folder.glob("shard-*.mcap"))
    assert 5 <= len(survivors) < 98, "the kill must land mid-generation"
    assert not (folder / "manifest.json").exists()
    for path in survivors:  # whatever carries a final name is complete
        with ShardReader(open_store(path.parent), path.name) as reader:
            assert sum(len(b.transitions) for b in reader.blocks()) == 4096
    listed = smgen("ls", "--lake", killed_lake).output
    assert "grid-seed4-MME" not in listed
    info = smgen("info", "--lake", killed_lake, "grid-seed4-MME")
    assert info.exit_code == 2 and "incomplete" in info.output
    stamps = {p.name: p.stat().st_mtime_ns for p in survivors}

    assert smgen(*args, "--lake", killed_lake).exit_code == 0
    assert {p.name: p.stat().st_mtime_ns for p in survivors} == stamps, "complete shards must not be rewritten"
    assert smgen(*args, "--lake", clean_lake).exit_code == 0
    assert files_of(folder) == files_of(clean_lake / "grid-seed4-MME")
    resumed, clean = (
        json.loads((lake / "grid-seed4-MME" / "manifest.json").read_text()) for lake in (killed_lake, clean_lake)
    )
    # the record of what made the bytes says that some parts came from the killed command
    assert f"{len(survivors)} of 99 parts were written by an earlier command" == resumed["software"].pop("note")
    assert resumed == clean
    assert not list(folder.glob("*.partial")) and not (folder / "generation.json").exists()


def test_a_deleted_shard_is_regenerated_identically(tmp_path):
    args = [
        "generate",
        "--setup",
        "grid",
        "--mode",
        "MEM",
        "--transitions",
        5000,
        "--shard-size",
        2000,
        "--lake",
        tmp_path,
    ]
    assert smgen(*args).exit_code == 0
    folder = tmp_path / "grid-seed0-MEM"
    before = files_of(folder)
    manifest = (folder / "manifest.json").read_bytes()
    (folder / "shard-00001.mcap").unlink()
    assert smgen("info", "--lake", tmp_path, "grid-seed0-MEM").exit_code == 0  # still listed until repaired
    again = smgen(*args)
    assert again.exit_code == 0 and "written" in again.output
    assert files_of(folder) == before
    repaired, original = json.loads((folder / "manifest.json").read_text()), json.loads(manifest)
    assert repaired["software"].pop("note") == "3 of 4 parts were written by an earlier command"
    assert repaired == original  # the same record, but for what it says of the parts kept


def test_progress_bar_is_quiet_without_a_terminal(tmp_path):
    proc = subprocess.run(
        [
            str(BIN / "smgen"),
            "generate",
            "--setup",
            "grid",
            "--mode",
            "MM",
            "--transitions",
            "2000",
            "--lake",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0 and proc.stderr == ""
    assert proc.stdout.strip().split("\t") == ["grid-seed0-MM", str(tmp_path / "grid-seed0-MM"), "written"]


def test_worlds_derive_their_seeds(tmp_path):
    out = smgen(
        "generate",
        "--setup",
        "grid6",
        "--mode",
        "MME",
        "--worlds",
        2,
        "--seed",
        7,
        "--transitions",
        1500,
        "--lake",
        tmp_path,
    )
    assert out.exit_code == 0, out.output
    assert "grid6-seed7-MME" in out.output and "grid6-seed8-MME" in out.output
    ds = Dataset.open("grid6-seed8-MME", tmp_path)
    assert ds.manifest.n_motor == 6 and ds.manifest.regular_sampling["count"] == 15625
    assert smgen("validate", "--lake", tmp_path, "grid6-seed7-MME", "grid6-seed8-MME").exit_code == 0


def test_python_dash_m_entry_point():
    """`python -m smspace.cli` is smtrain: how `--nproc` starts its ranks."""
    proc = subprocess.run([sys.executable, "-m", "smspace.cli", "--help"], capture_output=True, text=True)
    assert proc.returncode == 0 and "fit" in proc.stdout and "leaderboard" in proc.stdout, proc.stderr


def test_a_repair_racing_a_listing_never_hides_a_complete_dataset(grid_lake, tmp_path, monkeypatch):
    """An `ls` listed a manifest, a repair removed it before `ls` read it, then re-committed the
    same bytes (same version): the catalog recorded the version without the row and hid the
    dataset from every later `ls`. The catalog may be stale, never wrong."""
    import os
    import shutil

    import smspace.lake.catalog as catalog

    lake = tmp_path / "lake"
    shutil.copytree(grid_lake, lake)
    manifest = lake / "grid-seed3-MM" / "manifest.json"
    listed = catalog.manifest_versions(catalog.open_store(lake))
    data, st = manifest.read_bytes(), manifest.stat()
    manifest.unlink()  # the repair took it away between the listing and the read
    with monkeypatch.context() as patched:
        patched.setattr(catalog, "manifest_versions", lambda store: dict(listed))
        assert "grid-seed3-MM" not in catalog.rebuild_catalog(lake).column("id").to_pylist()
    manifest.write_bytes(data)  # ... and committed the same bytes again: the same version
    os.utime(manifest, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert catalog.manifest_versions(catalog.open_store(lake)) == listed
    assert "grid-seed3-MM" in catalog.read_catalog(lake).column("id").to_pylist()


def test_a_catalog_row_without_a_dataset_is_never_shown(grid_lake, tmp_path):
    import shutil

    import pyarrow as pa
    import pyarrow.parquet as pq

    lake = tmp_path / "lake"
    shutil.copytree(grid_lake, lake)
    assert smgen("ls", "--lake", lake).exit_code == 0  # a catalog in step with the listing
    table = pq.read_table(lake / "catalog.parquet")
    ghost = table.slice(0, 1).to_pylist()[0] | {"id": "grid-seed9-MM", "world_seed": 9}
    forged = pa.concat_tables([table, pa.Table.from_pylist([ghost], schema=table.schema)])
    pq.write_table(forged.replace_schema_metadata(table.schema.metadata), lake / "catalog.parquet")
    listed = smgen("ls", "--lake", lake, "--json").output
    assert "grid-seed9-MM" not in listed and listed.count('"id"') == 3


def test_one_scanner_finds_records_at_any_depth_outermost_only(tmp_path):
    """`smtrain ls` searched 3 folders deep, `report` 2 and `leaderboard` 4: a bench's runs (5 deep)
    were invisible to two of them. A record inside another's folder belongs to it."""
    from smspace.lake.scan import descend, folders_holding
    from smspace.lake.store import open_store

    for folder in ("a", "s/b", "s/grid/c", "bench/v1/entry/task/study/d", "a/checkpoints/old"):
        (tmp_path / folder).mkdir(parents=True)
        (tmp_path / folder / "config.json").write_text("{}")
    store = open_store(tmp_path)
    assert folders_holding(store, "config.json") == ["a", "bench/v1/entry/task/study/d", "s/b", "s/grid/c"]
    assert exists(descend(store, "s/grid/c"), "config.json")
    (tmp_path / "config.json").write_text("{}")
    assert folders_holding(store, "config.json") == [""]
    assert len(folders_holding(store, "config.json", itself=False)) == 4


def test_a_new_kind_of_storage_is_the_store_s_few_methods(tmp_path):
    """lake/store.py: a store implements its abstract methods and nothing else; whether a file
    exists, listings, hashes, a record's reading and writing are built on them for every kind."""
    import fnmatch
    import hashlib
    import io

    from smspace.lake.records import RUN_STATUS
    from smspace.lake.store import Store, canonical, entries, free_bytes, listing, sha256_of

    class MemoryStore(Store):
        def __init__(self, files: dict[str, bytes], url: str = "mem://lake"):
            self.files, self.url = files, url

        @property
        def name(self) -> str:
            return self.url.rsplit("/", 1)[-1]

        def child(self, name: str) -> MemoryStore:
            return MemoryStore(self.files, f"{self.url}/{name}")

        def is_folder(self) -> bool:
            return any(k.startswith(self.url + "/") for k in self.files)

        def is_file(self) -> bool:
            return self.url in self.files

        def make(self) -> None:
            pass

        def size(self, name: str) -> int:
            if f"{self.url}/{name}" not in self.files:
                raise FileNotFoundError(f"{self.url}/{name}")  # the contract: absent is this error
            return len(self.files[f"{self.url}/{name}"])

        def read(self, name: str, start: int = 0, length: int | None = None) -> bytes:
            data = self.files[f"{self.url}/{name}"]
            return data[start:] if length is None else data[start : start + length]

        def open(self, name: str, sequential: bool = False):
            return io.BytesIO(self.read(name))

        def put(self, name: str, data: bytes) -> None:
            self.files[f"{self.url}/{name}"] = data

        def create(self, name: str, data: bytes) -> None:
            if f"{self.url}/{name}" in self.files:
                raise FileExistsError(name)
            self.put(name, data)

        def delete(self, name: str) -> None:
            self.files.pop(f"{self.url}/{name}", None)

        def fingerprints(self, pattern: str) -> dict[str, str]:
            prefix = self.url + "/"
            names = [k[len(prefix) :] for k in self.files if k.startswith(prefix)]
            return {n: str(len(self.files[prefix + n])) for n in names if fnmatch.fnmatch(n, pattern)}

    store = MemoryStore({})
    run = store.child("run")
    RUN_STATUS.write(run, {"state": "created", "step": 0, "message": ""})
    run.create("checkpoint.pt", b"x" * 10)
    assert RUN_STATUS.read(run)["state"] == "created" and exists(run, "status.json") and not exists(run, "nope")
    assert listing(run, "*") == ["checkpoint.pt", "status.json"] == entries(run)
    assert sha256_of(run, "checkpoint.pt") == hashlib.sha256(b"x" * 10).hexdigest()
    assert canonical(run) == "mem://lake/run" and free_bytes(run) is None
    with pytest.raises(FileExistsError):
        run.create("checkpoint.pt", b"y")
    abstract = sorted(Store.__abstractmethods__)
    assert abstract == ["child", "create", "delete", "fingerprints", "is_file", "is_folder", "make", "name", "open",
                        "put", "read", "size"], abstract  # fmt: skip
