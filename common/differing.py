"""Which terms two records differ in: the one comparison behind every "made on other terms"
refusal, every "changed since it last ran" line and every "extended, recorded" (train/terms.py),
so that a key missing on one side, or one an older record never held, is judged the same way
everywhere."""

from __future__ import annotations

import json
from collections.abc import Callable, Collection, Mapping
from typing import Any


def differing(
    a: Mapping[str, Any], b: Mapping[str, Any], ignore: Collection[str] = (), within: Collection[str] | None = None
) -> list[str]:
    """The keys whose values differ, sorted (a key missing on one side differs). `within`: only
    these keys count (those an older record held; a field it never recorded is unknown, not
    different)."""
    keys = a.keys() | b.keys()
    if within is not None:
        keys &= set(within)
    return sorted(k for k in keys if k not in ignore and a.get(k) != b.get(k))


def shown_json(value: Any) -> str:
    """A value as a record holds it ("(unset)" for one that is missing)."""
    return "(unset)" if value is None else json.dumps(value, default=str)


def described(
    was: Mapping[str, Any],
    now: Mapping[str, Any],
    shown: Callable[[Any], str] = shown_json,
    prefix: str = "",
    ignore: Collection[str] = (),
) -> list[str]:
    """One phrase per differing key, "key old -> new" (`prefix`: the section it sits in)."""
    return [f"{prefix}{k} {shown(was.get(k))} -> {shown(now.get(k))}" for k in differing(was, now, ignore)]
