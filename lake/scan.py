"""Where records lie below a folder: one scanner for run folders (config.json), benchmark results
(bench.json) and whatever else a command looks for, local or on object storage, the same for
`smtrain ls`, `report`, `leaderboard` and the API."""

from __future__ import annotations

from smspace.lake.store import Store, listing

MAX_DEPTH = 8  # folders below the given one: a study's grid inside a bench's task is 5 deep


def patterns(name: str, *, itself: bool = True) -> list[str]:
    """The globs `folders_holding` lists, shallowest first."""
    return ["*/" * depth + name for depth in range(0 if itself else 1, MAX_DEPTH + 1)]


def folders_holding(store: Store, name: str, *, itself: bool = True) -> list[str]:
    """The outermost folders at or below `store` (`itself`: the folder given counts) that hold a
    file `name`, as paths relative to it ("" for the folder itself): a record inside another's
    folder (a run's own sub-folders) belongs to it, not a second find."""
    found: list[str] = []
    for pattern in patterns(name, itself=itself):
        for path in listing(store, pattern):
            folder = path.rsplit("/", 1)[0] if "/" in path else ""
            if not any(f == "" or folder == f or folder.startswith(f + "/") for f in found):
                found.append(folder)
    return sorted(found)


def descend(store: Store, folder: str) -> Store:
    """The store of a folder `folders_holding` returned."""
    for part in filter(None, folder.split("/")):
        store = store.child(part)
    return store
