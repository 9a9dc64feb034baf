"""Whether a stored file is the one its manifest records: readers never train on, export or show
bytes that are not the recorded ones, and generation never calls a damaged dataset complete.

A file's size is checked first, then its content: on object storage the ETag of a single PUT is the
MD5 of its bytes, so where the manifest records that MD5 one metadata request is witness enough;
otherwise (a local file, a multipart upload, a manifest without MD5s) the file is hashed whole.
"""

from __future__ import annotations

from typing import Any

from smspace.common.errors import DatasetCorrupt
from smspace.lake.store import Store


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
    if md5 is not None and store.etag(name) == md5:
        return None
    if store.sha256(name) != entry["sha256"]:
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
