"""Code of other packages, registered through entry points (setups, models): found by name, loaded
when needed, recorded by what it is (distribution, version, a hash of its code), and guarded, so
that whatever a plugin raises reaches the user as one line naming the plugin, its entry point and
the exception as raised, never relabelled and never a traceback (SMSPACE_TRACEBACK=1 prints the
plugin's own traceback above that line)."""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import cache
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any

from smspace.common.differing import described
from smspace.common.errors import SmspaceError, one_line


class PluginError(SmspaceError):
    """A plugin's own code raised, or broke the contract smspace holds it to."""


@dataclass(frozen=True)
class Plugin:
    """What a registered name resolved to: recorded in manifests and run configs, so that a changed
    plugin is seen as changed (its version or code hash differ)."""

    kind: str  # "setup" or "model"
    name: str
    entry_point: str  # module:attribute
    distribution: str
    version: str
    code_sha256: str  # over the .py files of the entry point's top-level package

    @property
    def label(self) -> str:
        return f"{self.kind} {self.name!r} ({self.entry_point})"

    def record(self) -> dict[str, str]:
        return {
            "entry_point": self.entry_point,
            "distribution": self.distribution,
            "version": self.version,
            "code_sha256": self.code_sha256,
        }


@cache
def registered(group: str) -> dict[str, EntryPoint]:
    """The entry points of a group by name (nothing loaded)."""
    return {ep.name: ep for ep in entry_points(group=group)}


@cache
def others(group: str, kind: str, builtin: tuple[str, ...]) -> dict[str, EntryPoint]:
    """The entry points of a group but those named like one of smspace's own: smspace's wins, and
    that is said once per process (on stderr) rather than the plugin being ignored without a word."""
    found = registered(group)
    for name in sorted(set(found) & set(builtin)):
        ep = found[name]
        dist = getattr(getattr(ep, "dist", None), "name", None) or "a package"
        print(
            f"smspace: note: the {kind} {name!r} of {dist} ({ep.value}) is not used: smspace's own {kind} "
            "has that name; register it under another",
            file=sys.stderr,
            flush=True,
        )
    return {name: ep for name, ep in found.items() if name not in builtin}


@dataclass
class Registry:
    """The things of one kind a run may name (setups, models): smspace's own first, then those
    other packages register under `group`, each loaded once, when first named. `builtin` gives one
    of smspace's own by name (imported only then: the command line never imports torch for its
    choices); `pick` finds the named thing in what an entry point loaded (None: not there)."""

    kind: str
    group: str
    builtin_names: tuple[str, ...]
    builtin: Callable[[str], Any]
    pick: Callable[[Any, str], Any] = lambda found, name: found
    _loaded: dict[str, tuple[Any, Plugin | None]] = field(default_factory=dict, repr=False)

    def names(self) -> tuple[str, ...]:
        return (*self.builtin_names, *sorted(others(self.group, self.kind, self.builtin_names)))

    def get(self, name: str) -> Any:
        return self._load(name)[0]

    def plugin(self, name: str) -> Plugin | None:
        """The package it comes from (None: smspace's own)."""
        return self._load(name)[1]

    def label(self, name: str) -> str:
        return label(self.kind, name, self.plugin(name))

    def _load(self, name: str) -> tuple[Any, Plugin | None]:
        if name not in self._loaded:
            self._loaded[name] = self._find(name)
        return self._loaded[name]

    def _find(self, name: str) -> tuple[Any, Plugin | None]:
        if name in self.builtin_names:
            return self.builtin(name), None
        ep = others(self.group, self.kind, self.builtin_names).get(name)
        if ep is None:
            raise SmspaceError(f"unknown {self.kind} {name!r} (choose from {', '.join(self.names())})")
        found, plugin = load(self.kind, ep)
        picked = self.pick(found, name)
        if picked is None:
            raise SmspaceError(
                f"the entry point {ep.value} of {self.kind} {name!r} declares no {self.kind} named {name!r}"
            )
        return picked, plugin


def describe(kind: str, ep: EntryPoint) -> Plugin:
    dist = getattr(ep, "dist", None)
    return Plugin(
        kind,
        ep.name,
        ep.value,
        dist.name if dist is not None else "unknown",
        dist.version if dist is not None else "unknown",
        code_hash(ep.module),
    )


def code_hash(module: str) -> str:
    """sha256 (16 hex digits) of the source of `module`'s top-level package: every .py file under
    it, by relative path. Found without importing it."""
    top = module.split(".")[0]
    try:
        spec = importlib.util.find_spec(top)
    except (ImportError, ValueError):
        spec = None
    if spec is None:
        return "unknown"
    if spec.submodule_search_locations:
        roots = [Path(p) for p in spec.submodule_search_locations]
        files = sorted((f.relative_to(root).as_posix(), f) for root in roots for f in root.rglob("*.py"))
    elif spec.origin and Path(spec.origin).is_file():
        files = [(Path(spec.origin).name, Path(spec.origin))]
    else:
        return "unknown"
    digest = hashlib.sha256()
    for name, path in files:
        digest.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def load(kind: str, ep: EntryPoint) -> tuple[Any, Plugin]:
    """The object an entry point names, and the plugin's record. Importing a plugin runs its code:
    whatever that raises (SystemExit included) is one line."""
    plugin = describe(kind, ep)
    with guarded(plugin, "being imported"):
        return ep.load(), plugin


@contextlib.contextmanager
def guarded(plugin: Plugin | None, what: str) -> Iterator[None]:
    """Run a plugin's code: any exception it raises becomes one line that names the plugin, what it
    was doing and the exception as raised. Code of smspace itself (plugin None) is not wrapped."""
    if plugin is None:
        yield
        return
    try:
        yield
    except SmspaceError:
        raise
    except (Exception, SystemExit) as e:
        raise PluginError(f"{plugin.label} raised {what}: {one_line(e, with_type=True)}") from e


def label(kind: str, name: str, plugin: Plugin | None) -> str:
    """How messages name a setup or model: a plugin's with its entry point."""
    return plugin.label if plugin is not None else f"{kind} {name!r}"


def changes(was: dict[str, Any], now: dict[str, Any]) -> str:
    """What differs between two records, as "key old -> new, ..." (a plugin updated, say)."""
    return ", ".join(described(was, now, shown=str))
