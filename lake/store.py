"""Where a lake lives: a local folder, or a prefix on object storage reached through fsspec.

A `Store` is one folder of the lake (the lake itself or a dataset in it). Readers and writers
use only what both kinds can promise: whole objects written in one step (a rename locally, one
PUT on S3), create-only writes for the commit point, ranged reads, listings. Nothing renames
on object storage (docs/FORMAT.md, "Commit protocol").
"""

from __future__ import annotations

import base64
import contextlib
import fnmatch
import hashlib
import os
import shutil
import stat
import time
import uuid
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

from smspace.common.atomic import create_exclusive, write_atomic
from smspace.common.atomic import remove_partials as remove_partial_files
from smspace.common.errors import DatasetCorrupt, SmspaceError, one_line
from smspace.common.locks import HeldLock, hold_lock

LOCAL_SCHEMES = ("", "file")
READ_BLOCK = 1 << 16  # the summary of a shard comes down in one or two requests of this size


def is_url(ref: str | Path) -> bool:
    return isinstance(ref, str) and "://" in ref


def within(inner: Store | str | Path, outer: Store | str | Path) -> bool:
    """Whether `inner` is `outer` or lies inside it: local folders compared resolved (links
    followed), object storage by URL prefix. Outputs must never land inside their own inputs."""
    a, b = (x.url if isinstance(x, Store) else str(x) for x in (inner, outer))
    if is_url(a) or is_url(b):
        return (a.rstrip("/") + "/").startswith(b.rstrip("/") + "/")
    return Path(a).resolve().is_relative_to(Path(b).resolve())


def check_name(folder: str, name: str) -> None:
    """A file of a folder is a plain name: nothing a manifest names can leave the folder."""
    if "/" in name or "\\" in name or name in ("", ".", ".."):
        raise DatasetCorrupt(f"{folder}/{name}: not a file name inside the dataset")


class Store(ABC):
    """One folder of a lake; every name is a plain file name in it (no '/').

    What a kind of storage must do, and no more: name a sub-folder, tell a file's size, read it
    (whole, a range, or as a file object), list files with a version tag, write a file whole
    (unconditionally, only if absent, only if still at a version), delete one, lock one, make the
    folder and say what its own name holds. Everything else (whether a file exists, a listing, a
    hash, a folder's tidying) is built on these by the functions below, once for every kind."""

    url: str

    def __str__(self) -> str:
        return self.url

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.url!r})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Store) and other.url == self.url

    def __hash__(self) -> int:
        return hash(self.url)

    @property
    @abstractmethod
    def name(self) -> str: ...

    @property
    def local_path(self) -> Path | None:
        """The folder on this machine, or None for a folder on object storage."""
        return None

    @abstractmethod
    def child(self, name: str) -> Store: ...

    @abstractmethod
    def is_folder(self) -> bool:
        """Whether this folder holds anything (object stores have no empty folders)."""

    @abstractmethod
    def is_file(self) -> bool:
        """Whether this folder's own name is taken by a file."""

    @abstractmethod
    def make(self) -> None:
        """Create this folder (a no-op on object storage)."""

    @abstractmethod
    def size(self, name: str) -> int:
        """Bytes of a regular file; FileNotFoundError when absent, DatasetCorrupt when not regular."""

    @abstractmethod
    def read(self, name: str, start: int = 0, length: int | None = None) -> bytes:
        """The whole file, or bytes [start, start + length): one request on object storage."""

    @abstractmethod
    def open(self, name: str, sequential: bool = False) -> BinaryIO:
        """A reader: seekable, small reads from READ_BLOCK-sized requests (an MCAP summary); or,
        `sequential`, one with large requests (hashing, whole-file reads)."""

    @abstractmethod
    def put(self, name: str, data: bytes) -> str | None:
        """Write a whole file at once: readers see the old one or the new one, never a part.
        Returns the new version where the store has versions (an ETag on object storage)."""

    @abstractmethod
    def create(self, name: str, data: bytes) -> str | None:
        """Write a whole file only if none exists: FileExistsError otherwise (the commit point)."""

    def replace(self, name: str, data: bytes, version: str | None) -> str | None:
        """Write a whole file only if it is still at `version` (None: only if absent), so that two
        writers of one file never overwrite each other unseen: WriteConflict otherwise. Local
        folders rely on their writer's lock instead and simply replace it."""
        return self.put(name, data)

    @abstractmethod
    def delete(self, name: str) -> None:
        """Remove a file; an absent one is not an error."""

    @abstractmethod
    def fingerprints(self, pattern: str) -> dict[str, str]:
        """{relative path: version tag} of the files matching a glob such as '*/manifest.json'; the
        tag changes whenever the file is rewritten (ETag on S3, size and mtime locally)."""

    def lock(self, name: str, busy: str, wait: bool = False) -> HeldLock:
        """An exclusive lock on a file of the folder, held until released (or a `with` block
        ends): if another process holds it, wait (`wait`) or refuse at once with `busy`. Where the
        store has no locks (object storage) nothing is held: writers rely on its conditional
        writes instead."""
        return HeldLock(None)


# --- built on the store's own operations, the same for every kind --------------------------------


def exists(store: Store, name: str) -> bool:
    """Whether `name` is a regular file of the folder."""
    try:
        store.size(name)
    except (FileNotFoundError, DatasetCorrupt):
        return False
    return True


def listing(store: Store, pattern: str) -> list[str]:
    """The files matching a glob, sorted."""
    return sorted(store.fingerprints(pattern))


def sha256_of(store: Store, name: str) -> str:
    h = hashlib.sha256()
    with store.open(name, sequential=True) as fh:
        for block in iter(lambda: fh.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()


def where(store: Store) -> Path | str:
    """The folder as messages and listings show it: a Path locally, else its URL."""
    return store.local_path or store.url


def canonical(store: Store) -> str:
    """How a record (a run's config) names the folder: an absolute path, or the URL."""
    local = store.local_path
    return str(local.resolve()) if local is not None else store.url


def entries(store: Store) -> list[str]:
    """Every name in the folder: files, and sub-folders where the store has folders."""
    local = store.local_path
    if local is None:
        return listing(store, "*")
    return [p.name for p in local.iterdir()] if local.is_dir() else []


def etag(store: Store, name: str) -> str | None:
    """The MD5 of a file written by one PUT, as object storage reports it; None where there is no
    such witness (local files, multipart uploads)."""
    return store.etag(name) if isinstance(store, RemoteStore) else None


def remove_partials(store: Store) -> None:
    """Drop what killed writers left; object storage never has partial objects."""
    if store.local_path is not None:
        remove_partial_files(store.local_path)


def remove_folder(store: Store) -> None:
    """Remove an emptied folder itself, where folders exist (object storage has none)."""
    if isinstance(store, LocalStore):
        store.remove_folder()


def free_bytes(store: Store) -> int | None:
    """Free space for new files, or None where there is no such limit to check (object storage)."""
    probe = store.local_path
    if probe is None:
        return None
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    return shutil.disk_usage(probe).free


class LocalStore(Store):
    """A folder on this machine's filesystem: writes go through a temporary name and a rename."""

    def __init__(self, path: Path | str, root: Path | None = None):
        self.path = Path(path)
        self.url = str(self.path)
        self._root = root  # the folder the user named; its sub-folders are smspace's own

    def _refuse_links(self) -> None:
        """Writes never leave the tree the user named: a sub-folder of it (a run folder of a study,
        a run's tensorboard/ or embeddings/, a dataset folder) that is a symbolic link is refused.
        The folder the user named may itself be a link: that was their choice."""
        if self._root is None:
            return
        at = self._root
        for part in self.path.relative_to(self._root).parts:
            at = at / part
            if at.is_symlink():
                raise SmspaceError(f"{at} is a symbolic link; smspace writes only inside the folders it made")

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def local_path(self) -> Path:
        return self.path

    def remove_folder(self) -> None:
        self._refuse_links()
        shutil.rmtree(self.path, ignore_errors=True)

    def child(self, name: str) -> LocalStore:
        check_name(self.url, name)
        return LocalStore(self.path / name, root=self._root or self.path)

    def file(self, name: str) -> Path:
        """A regular file directly inside this folder, never a link, device or FIFO."""
        check_name(self.url, name)
        path = self.path / name
        st = os.lstat(path)  # FileNotFoundError propagates: a missing file is the caller's to report
        if not stat.S_ISREG(st.st_mode):
            raise DatasetCorrupt(f"{path}: not a regular file (a link, folder or special file)")
        return path

    def is_folder(self) -> bool:
        return self.path.is_dir()

    def is_file(self) -> bool:
        return self.path.exists() and not self.path.is_dir()

    def make(self) -> None:
        self._refuse_links()
        if self.is_file():
            raise SmspaceError(f"{self.path} exists and is not a folder")
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise SmspaceError(f"cannot create folder {self.path}: {e.strerror or e}") from e

    def size(self, name: str) -> int:
        return self.file(name).stat().st_size

    def read(self, name: str, start: int = 0, length: int | None = None) -> bytes:
        if start == 0 and length is None:
            return self.file(name).read_bytes()
        with open(self.file(name), "rb") as fh:
            if length is None:
                fh.seek(start)
                return fh.read()
            return os.pread(fh.fileno(), length, start)

    def open(self, name: str, sequential: bool = False) -> BinaryIO:
        return open(self.file(name), "rb")

    def put(self, name: str, data: bytes) -> None:
        check_name(self.url, name)
        self._refuse_links()
        write_atomic(self.path / name, data)

    def create(self, name: str, data: bytes) -> None:
        check_name(self.url, name)
        self._refuse_links()
        create_exclusive(self.path / name, data)

    def delete(self, name: str) -> None:
        check_name(self.url, name)
        self._refuse_links()
        (self.path / name).unlink(missing_ok=True)

    def fingerprints(self, pattern: str) -> dict[str, str]:
        out = {}
        for path in self.path.glob(pattern):
            st = path.lstat()
            if stat.S_ISREG(st.st_mode):
                out[path.relative_to(self.path).as_posix()] = f"{st.st_size}-{st.st_mtime_ns}"
        return out

    def lock(self, name: str, busy: str, wait: bool = False) -> HeldLock:
        self._refuse_links()
        return hold_lock(self.path / name, busy, wait)


class RemoteStore(Store):
    """A prefix on an fsspec filesystem (s3://, gs://, memory://…): one object per file, no rename.

    Every write carries a token of its own in the object's metadata: a write whose answer was lost
    is retried by the client (the same request, the same token) and then refused (412) by the
    condition it set; the token tells that refusal (our write landed) from another writer's object."""

    def __init__(self, fs: Any, root: str, url: str):
        self.fs, self.root, self.url = fs, root.rstrip("/"), url.rstrip("/")

    @property
    def name(self) -> str:
        return self.root.rsplit("/", 1)[-1]

    def child(self, name: str) -> RemoteStore:
        check_name(self.url, name)
        return RemoteStore(self.fs, f"{self.root}/{name}", f"{self.url}/{name}")

    def _key(self, name: str) -> str:
        check_name(self.url, name)
        return f"{self.root}/{name}"

    def is_folder(self) -> bool:
        """Whether the prefix holds anything; one LIST request, which also proves the bucket exists,
        the credentials work and the endpoint answers (each failure named in one line)."""
        with remote_errors(self.url, self.fs):
            try:
                return bool(self.fs.ls(self.root, detail=False, refresh=True))
            except FileNotFoundError as e:
                if _missing_bucket(e):
                    raise
                return False

    def is_file(self) -> bool:
        self.is_folder()  # a missing bucket or bad credentials fail here, not as "no such file"
        with remote_errors(self.url, self.fs):
            return self.fs.isfile(self.root)

    def make(self) -> None:
        if self.is_file():
            raise SmspaceError(f"{self.url} exists and is not a folder")

    def size(self, name: str) -> int:
        key = self._key(name)
        with remote_errors(self.url, self.fs):
            info = self.fs.info(key, refresh=True)
        if info.get("type") != "file":
            raise DatasetCorrupt(f"{self.url}/{name}: not a file")
        return int(info["size"])

    def read(self, name: str, start: int = 0, length: int | None = None) -> bytes:
        key = self._key(name)
        if start == 0 and length is None:
            # fresh: s3fs sizes a whole-object read from its listing cache, which another writer outdates
            return self._transfer(name, lambda: (self.fs.invalidate_cache(key), self.fs.cat_file(key))[1])
        end = None if length is None else start + length
        return self._transfer(name, lambda: self.fs.cat_file(key, start=start, end=end))

    def _transfer(self, name: str, fetch: Callable[[], bytes]) -> bytes:
        """A read, tried again when the transfer itself failed (a checksum mismatch, a truncated
        body): the stored bytes are called corrupt only by what reads them whole and intact."""
        for attempt in range(TRANSFER_ATTEMPTS):
            try:
                with remote_errors(self.url, self.fs):
                    return fetch()
            except TransferFailed as e:
                if attempt == TRANSFER_ATTEMPTS - 1:
                    raise TransferFailed(
                        f"{self.url}/{name}: the transfer failed {TRANSFER_ATTEMPTS} times ({e})"
                    ) from None
                time.sleep(0.2 * 2**attempt)
        raise AssertionError("unreachable")

    def etag(self, name: str) -> str | None:
        key = self._key(name)
        with remote_errors(self.url, self.fs):
            info = self.fs.info(key, refresh=True)
        return _md5_etag(info.get("ETag") or info.get("etag"))

    def open(self, name: str, sequential: bool = False) -> BinaryIO:
        block = 1 << 24 if sequential else READ_BLOCK
        with remote_errors(self.url, self.fs):
            return self.fs.open(self._key(name), "rb", block_size=block, cache_type="readahead")

    def put(self, name: str, data: bytes) -> str | None:
        return self._put(name, data)

    def create(self, name: str, data: bytes) -> str | None:
        try:
            return self._put(name, data, IfNoneMatch="*")  # refused if the key exists
        except WriteConflict:
            raise FileExistsError(f"{self.url}/{name}") from None

    def replace(self, name: str, data: bytes, version: str | None) -> str | None:
        if version is None:
            return self._put(name, data, IfNoneMatch="*")
        return self._put(name, data, IfMatch=f'"{version}"')

    def _put(self, name: str, data: bytes, **condition: str) -> str | None:
        key = self._key(name)
        token = uuid.uuid4().hex  # names this write, not a draw of any result
        digest = hashlib.md5(data, usedforsecurity=False)
        try:
            with remote_errors(self.url, self.fs):
                out = self.fs.pipe_file(
                    key,
                    data,
                    Metadata={WRITE_TOKEN: token},
                    ContentMD5=base64.b64encode(digest.digest()).decode(),  # the server checks what arrived
                    **condition,
                )
        except FileNotFoundError:
            if "IfMatch" not in condition:
                raise
            raise WriteConflict(self.url) from None  # the version we expected was deleted (404, not 412)
        except WriteConflict:
            if condition and self._written_by(token, key):  # our first attempt landed, its answer was lost
                return digest.hexdigest()
            raise
        return _md5_etag((out or {}).get("ETag"))

    def _written_by(self, token: str, key: str) -> bool:
        with remote_errors(self.url, self.fs):
            self.fs.invalidate_cache(key)
            return self.fs.metadata(key).get(WRITE_TOKEN) == token

    def delete(self, name: str) -> None:
        key = self._key(name)
        with remote_errors(self.url, self.fs), contextlib.suppress(FileNotFoundError):
            self.fs.rm_file(key)

    def fingerprints(self, pattern: str) -> dict[str, str]:
        with remote_errors(self.url, self.fs):
            self.fs.invalidate_cache(self.root)
            found = self.fs.glob(f"{self.root}/{pattern}", detail=True)
        prefix = len(self.root) + 1
        return {
            path[prefix:]: str(info.get("ETag") or info.get("etag") or f"{info.get('size')}-{info.get('mtime')}").strip(
                '"'
            )
            for path, info in found.items()
            if fnmatch.fnmatch(path[prefix:], pattern) and info.get("type", "file") == "file"
        }


WRITE_TOKEN = "smspace-write"  # object metadata: the token of the write that stored it
TRANSFER_ATTEMPTS = 3


class WriteConflict(FileExistsError):
    """A conditional write refused (412): the object is not the version the writer expected."""


class StorageUnreachable(SmspaceError):
    """The endpoint did not answer (a time-out, a refused connection) after every attempt: nothing
    may read this as "absent" or "damaged" and go on, so each request of a frozen endpoint is the
    last of its command (README: the bound)."""


class TransferFailed(SmspaceError):
    """The bytes did not arrive whole (a checksum mismatch, a cut connection); the stored object may
    be sound."""


def _md5_etag(tag: Any) -> str | None:
    """An ETag that is the MD5 of the object's bytes (one PUT), else None (a multipart upload)."""
    tag = str(tag or "").strip('"')
    return tag if len(tag) == 32 and all(c in "0123456789abcdef" for c in tag) else None


@contextlib.contextmanager
def remote_errors(url: str, fs: Any = None) -> Iterator[None]:
    """Whatever s3fs, botocore or aiohttp raise becomes one line naming the place; a missing file
    stays FileNotFoundError (callers decide what absence means), a refused conditional write is a
    WriteConflict, a damaged transfer a TransferFailed (worth another attempt). A request the
    endpoint left unanswered is StorageUnreachable even where s3fs or fsspec passed over its error
    (an `isfile` that returns False, a parent listing tried "just in case"): `fs` counts them."""
    before = getattr(fs, "unanswered", 0)

    def swallowed() -> StorageUnreachable | None:
        if getattr(fs, "unanswered", 0) == before:
            return None
        return StorageUnreachable(f"{url}: {_explain(fs.last_unanswered)}")

    try:
        yield
    except (WriteConflict, TransferFailed):
        raise
    except Exception as e:
        missed = None if is_unreachable(e) else swallowed()
        if missed is not None:
            raise missed from None
        if _status(e) == 412:  # by the status code: a key containing "412" is no precondition failure
            raise WriteConflict(url) from None
        if isinstance(e, FileNotFoundError):
            if _missing_bucket(e):
                raise SmspaceError(f"{url}: no such bucket") from None
            raise
        if isinstance(e, PermissionError):
            raise SmspaceError(
                f"{url}: access denied ({one_line(e)}); check the credentials (AWS_ACCESS_KEY_ID…)"
            ) from None
        damaged = damaged_transfer(e)
        if damaged:
            raise TransferFailed(f"{url}: {damaged}") from None
        raise (StorageUnreachable if is_unreachable(e) else SmspaceError)(f"{url}: {_explain(e)}") from None
    missed = swallowed()
    if missed is not None:
        raise missed


def _chain(e: BaseException) -> Iterator[BaseException]:
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        yield e
        e = e.__cause__ or e.__context__


def _status(e: BaseException) -> int | None:
    """The HTTP status of the answer behind an error (botocore's ClientError, however wrapped)."""
    for link in _chain(e):
        response = getattr(link, "response", None)
        if isinstance(response, dict):
            status = response.get("ResponseMetadata", {}).get("HTTPStatusCode")
            if status is not None:
                return int(status)
    return None


TRANSFER_ERRORS = ("FlexibleChecksumError", "ResponseStreamingError", "IncompleteRead", "ClientPayloadError")


def damaged_transfer(e: BaseException) -> str | None:
    """What failed in transit behind an error (a cut body, a bad checksum), or None."""
    for link in _chain(e):
        if type(link).__name__ in TRANSFER_ERRORS:
            return f"{type(link).__name__}: {one_line(link)}"
    return None


def _missing_bucket(e: BaseException) -> bool:
    return "NoSuchBucket" in repr(e) or "bucket does not exist" in str(e).lower()


def is_unreachable(e: BaseException) -> bool:
    """Whether an error means the endpoint did not answer (a time-out, no connection), as opposed
    to an answer: a refusal, an absence, or bytes damaged on the way."""
    return not damaged_transfer(e) and _explain(e).startswith(UNREACHABLE)


UNREACHABLE = ("cannot reach the storage endpoint", "the storage endpoint did not answer")


def _explain(e: BaseException) -> str:
    name = type(e).__name__
    if "Credential" in name or "InvalidAccessKeyId" in repr(e) or "SignatureDoesNotMatch" in repr(e):
        return f"access denied ({name}); check the credentials (AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY)"
    if "Connect" in name or "Endpoint" in name:
        return f"cannot reach the storage endpoint ({one_line(e)}); check AWS_ENDPOINT_URL"
    if "Timeout" in name or isinstance(e, TimeoutError):
        return f"the storage endpoint did not answer in time ({name}; SMSPACE_S3_READ_TIMEOUT sets the limit)"
    return f"{name}: {one_line(e)}"


def open_store(ref: str | Path | Store) -> Store:
    """A folder of the lake from a path or URL: plain paths and file:// stay local (rename-based
    writes, locks), any other fsspec URL is object storage (s3:// needs `pip install smspace[s3]`).
    A Store is returned as it is."""
    if isinstance(ref, Store):
        return ref
    if isinstance(ref, Path) or not is_url(ref):
        return LocalStore(Path(ref))
    scheme = ref.split("://", 1)[0].lower()
    if scheme in LOCAL_SCHEMES:
        return LocalStore(Path(ref.split("://", 1)[1]))
    import fsspec

    try:
        if scheme in ("s3", "s3a"):
            from smspace.lake.s3 import BoundedS3FileSystem  # needs s3fs: the [s3] extra

            fs = BoundedS3FileSystem(skip_instance_cache=True, **s3_options())
            root = fs._strip_protocol(ref)
        else:
            fs, root = fsspec.url_to_fs(ref)
    except ImportError:
        hint = "pip install 'smspace[s3]'" if scheme in ("s3", "s3a") else f"install the fsspec package for {scheme}://"
        raise SmspaceError(f"{ref}: the {scheme}:// scheme needs a package that is not installed; {hint}") from None
    except ValueError as e:
        raise SmspaceError(f"{ref}: unknown storage scheme {scheme!r} ({one_line(e)})") from None
    if not root.strip("/"):
        raise SmspaceError(f"{ref}: give a bucket (and optionally a prefix), e.g. s3://bucket/lake")
    return RemoteStore(fs, root, f"{scheme}://{root}")


def _env_number(name: str, default: float, kind: type = float) -> Any:
    raw = os.environ.get(name)
    if raw is None:
        return default
    try:
        value = kind(raw)
    except ValueError:
        raise SmspaceError(f"${name} must be a number, got {raw!r}") from None
    if not value > 0:
        raise SmspaceError(f"${name} must be positive, got {raw!r}")
    return value


def s3_options() -> dict[str, Any]:
    """Time limits and retries of every S3 request (README, "Scaling out"): a frozen endpoint gives
    one line after at most attempts x (connect + read timeout), never a hang."""
    connect = _env_number("SMSPACE_S3_CONNECT_TIMEOUT", 5.0)
    read = _env_number("SMSPACE_S3_READ_TIMEOUT", 20.0)
    attempts = _env_number("SMSPACE_S3_ATTEMPTS", 3, int)
    # total_max_attempts counts the first try; botocore's max_attempts would count only the retries
    retries = {"total_max_attempts": attempts, "mode": "standard"}
    config = {"connect_timeout": connect, "read_timeout": read, "retries": retries}
    # botocore's default streams a trailing checksum with every upload, which makes the body a file
    # and adds `Expect: 100-continue`, whose wait no time limit covers (against a frozen endpoint a
    # PUT would wait for ever); each PUT carries its Content-MD5 instead (RemoteStore._put), checked
    # by the server
    config["request_checksum_calculation"] = "when_required"
    return {"config_kwargs": config}
