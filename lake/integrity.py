"""Whether a stored file is the one its manifest records: readers never train on, export or show
bytes that are not the recorded ones, and generation never calls a damaged dataset complete.

A file's size is checked first, then its content: on object storage the ETag of a single PUT is the
MD5 of its bytes, so where the manifest records that MD5 one metadata request is witness enough;
otherwise (a local file, a multipart upload, a manifest without MD5s) the file is hashed whole.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import Any

from smspace.common.errors import DatasetCorrupt
from smspace.lake.store import Store, TransferFailed, etag, sha256_of

READS = 3  # whole reads of a file that does not match before anything is concluded


def file_problem(store: Store, entry: dict[str, Any]) -> str | None:
    """Why the file a manifest entry names differs from what it records, or None."""
    name = entry["file"]
    try:
        size = store.size(name)
    except FileNotFoundError:
        return "missing"
    except DatasetCorrupt as e:
        return str(e)
    if size != entry["bytes"]:
        return f"{size} bytes, the manifest records {entry['bytes']} (truncated or replaced)"
    md5 = entry.get("md5")
    if md5 is not None and etag(store, name) == md5:
        return None
    if sha256_of(store, name) != entry["sha256"]:
        return "its bytes differ from the manifest's sha256 (replaced or damaged)"
    return None


def check_file(store: Store, entry: dict[str, Any], dataset_id: str) -> None:
    """Raise, in one line, when a file of a dataset is not the recorded one."""
    problem = file_problem(store, entry)
    if problem:
        raise DatasetCorrupt(
            f"{store.url}/{entry['file']} is not the file dataset {dataset_id} records: {problem}; "
            f"`smgen validate` names every damaged file and re-running its `smgen generate` repairs them"
        )


def read_verified(
    store: Store, name: str, problem_of: Callable[[bytes], str | None], stored_sound: Callable[[], bool] = lambda: False
) -> tuple[bytes, str | None]:
    """A file read whole until `problem_of` finds nothing wrong with it. A read can fail in transit
    without the client noticing (a body cut or garbled on the way), so a file is called damaged only
    when the same wrong bytes come back twice and the storage does not vouch for the stored object
    (`stored_sound`: its ETag is the recorded MD5). Returns (bytes, None) for a good read, (bytes,
    problem) for a file stored so; raises TransferFailed when the reads never brought the file."""
    seen: list[bytes] = []
    for _ in range(READS):
        data = store.read(name)
        problem = problem_of(data)
        if problem is None:
            return data, None
        if data in seen and not stored_sound():
            return data, problem
        seen.append(data)
    why = "the storage holds it intact" if stored_sound() else "each brought other bytes"
    raise TransferFailed(
        f"{store.url}/{name}: {READS} reads did not bring the recorded file ({why}): "
        "the transfer is failing, not the file; try again"
    )


def content_problem(data: bytes, entry: dict[str, Any]) -> str | None:
    """Why bytes read whole are not the file a manifest entry records, or None."""
    if len(data) != entry["bytes"]:
        return f"{len(data)} bytes, manifest says {entry['bytes']} (truncated or replaced)"
    if hashlib.sha256(data).hexdigest() != entry["sha256"]:
        return "sha256 differs from the manifest"
    return None
