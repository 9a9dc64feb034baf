"""One canonical form per benchmark entry, so that one entry can never pass for two (or two for one).

A name is plain ASCII a page can show unescaped (letters, digits, `.`, `_`, `+`, `-`; compared
case-folded). Parameters are read as the model's own defaults type them (nanoGPT's configurator:
a default's type decides how a value is read), numbers are compared by value, a default spelled
out is dropped, and text is Unicode-normalised (NFKC) with control and invisible characters
refused. The folder of a result is its canonical form written without loss: readable where
every character is safe in a path, else a hash of the canonical parameters.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import math
import re
import unicodedata
from typing import Any

from smspace.common.errors import SmspaceError

NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]{0,63}")
KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,63}")
SAFE_FOLDER = re.compile(r"[A-Za-z0-9._+=,-]{1,120}")
MAX_TEXT = 200  # characters of a text parameter
MAX_ITEMS = 64  # items of a list parameter
INVISIBLE = {"Cc", "Cf", "Co", "Cs", "Cn", "Zl", "Zp"}  # control, format (zero-width), private, unassigned


def canonical_name(name: Any, where: str = "entry") -> str:
    if not isinstance(name, str) or not NAME.fullmatch(name):
        raise SmspaceError(
            f"{where} name {_shown(name)} is not a plain name (1-64 of A-Z a-z 0-9 . _ + -, a letter or digit first)"
        )
    return name


def canonical_text(value: str, where: str) -> str:
    text = unicodedata.normalize("NFKC", value)
    bad = [c for c in text if unicodedata.category(c) in INVISIBLE]
    if bad:
        raise SmspaceError(f"{where}: {_shown(value)} holds control or invisible characters ({_shown(''.join(bad))})")
    if text != text.strip():
        raise SmspaceError(f"{where}: {_shown(value)} begins or ends with white space")
    if len(text) > MAX_TEXT:
        raise SmspaceError(f"{where}: a value of {len(text)} characters (at most {MAX_TEXT})")
    return text


def canonical_value(value: Any, where: str, like: Any = inspect.Parameter.empty) -> Any:
    """A parameter's value in its one form: typed as the default `like` is (where there is one),
    numbers by value (64.0 is 64 where the default is an int or there is none), text normalised."""
    if isinstance(value, list):
        if like not in (inspect.Parameter.empty, None) and not isinstance(like, list | tuple):
            raise SmspaceError(f"{where}: a list is not a {type(like).__name__} (the default is {like!r})")
        if len(value) > MAX_ITEMS:
            raise SmspaceError(f"{where}: a list of {len(value)} items (at most {MAX_ITEMS})")
        item = like[0] if isinstance(like, list | tuple) and like else inspect.Parameter.empty
        return [canonical_value(v, f"{where}[{i}]", item) for i, v in enumerate(value)]
    if isinstance(like, list | tuple):
        raise SmspaceError(f"{where}: {_shown(value)} is not a list, as the default {list(like)!r} is")
    if isinstance(value, str):
        value = canonical_text(value, where)
        if isinstance(like, int | float):
            number = _number(value)
            if number is None:
                raise SmspaceError(f"{where}: {_shown(value)} is not a number (the default is {like!r})")
            value = number
    if isinstance(value, bool):
        if like is not inspect.Parameter.empty and like is not None and not isinstance(like, bool):
            raise SmspaceError(f"{where}: {value} is not a {type(like).__name__} (the default is {like!r})")
        return value
    if isinstance(value, int | float):
        if not math.isfinite(value):
            raise SmspaceError(f"{where}: {value} is not a finite number")
        if isinstance(like, bool):
            raise SmspaceError(f"{where}: {value} is not true or false (the default is {like!r})")
        if isinstance(like, float):
            return float(value)
        if float(value).is_integer() and abs(value) < 2**53:
            return int(value)
        if isinstance(like, int):
            raise SmspaceError(f"{where}: {value} is not a whole number (the default is {like!r})")
        return float(value)
    if isinstance(value, str):
        if like is not inspect.Parameter.empty and like is not None and not isinstance(like, str):
            raise SmspaceError(f"{where}: {_shown(value)} is not a {type(like).__name__} (the default is {like!r})")
        return value
    raise SmspaceError(f"{where}: a {type(value).__name__} is not a parameter value (numbers, text, true/false, lists)")


def _number(text: str) -> int | float | None:
    """'064' -> 64, '1e-3' -> 0.001; None when the text is not a number."""
    if re.fullmatch(r"[+-]?[0-9]+", text):
        return int(text)
    try:
        number = float(text)
    except ValueError:
        return None
    return number if math.isfinite(number) else None


def canonical_params(params: Any, defaults: dict[str, Any] | None, where: str) -> dict[str, Any]:
    """Sorted, typed, without the defaults spelled out. `defaults`: the model's keyword parameters
    and their defaults (None: not known here, every key is kept as given); a key not among them is
    refused."""
    if not isinstance(params, dict):
        raise SmspaceError(f"{where}: parameters are a table of key = value, not a {type(params).__name__}")
    out = {}
    for key in sorted(params, key=str):
        if not isinstance(key, str) or not KEY.fullmatch(key):
            raise SmspaceError(f"{where}: parameter {_shown(key)} is not a plain key (a Python identifier, 1-64 chars)")
        if defaults is not None and key not in defaults:
            known = ", ".join(sorted(defaults)) or "none"
            raise SmspaceError(f"{where}: unknown parameter {key!r} (it takes: {known})")
        like = defaults.get(key, inspect.Parameter.empty) if defaults is not None else inspect.Parameter.empty
        value = canonical_value(params[key], f"{where}, parameter {key}", like)
        if like is not inspect.Parameter.empty and _same(value, like):
            continue  # the default spelled out: the same entry as without it
        out[key] = value
    return out


def _same(value: Any, default: Any) -> bool:
    try:
        return (type(value) is type(default) and value == default) or (
            isinstance(default, tuple) and value == list(default)
        )
    except Exception:  # an exotic default compares as different
        return False


def model_defaults(cls: Any) -> dict[str, Any] | None:
    """A model class's keyword parameters beyond the five every model takes, with their defaults
    (inspect.Parameter.empty where there is none); None when its signature cannot be read."""
    try:
        signature = inspect.signature(cls)
    except (TypeError, ValueError):
        return None
    named = [p for p in signature.parameters.values() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    if any(p.kind == p.VAR_KEYWORD for p in signature.parameters.values()):
        return None
    return {p.name: p.default for p in named[5:]}


def canonical_json(params: dict[str, Any]) -> str:
    return json.dumps(params, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def folder_of(name: str, params: dict[str, Any]) -> str:
    """The entry's folder, lossless: NAME, NAME,key=value,… where that is path-safe, else NAME,params-HASH."""
    if not params:
        return name
    readable = name + "," + ",".join(f"{k}={canonical_json(v)}" for k, v in params.items())
    if SAFE_FOLDER.fullmatch(readable):
        return readable
    return f"{name},params-{hashlib.sha256(canonical_json(params).encode()).hexdigest()[:16]}"


def label_of(name: str, params: dict[str, Any]) -> str:
    """How tables name the entry: NAME, or NAME (key=value, …) with values as canonical JSON."""
    return name if not params else f"{name} (" + ", ".join(f"{k}={canonical_json(v)}" for k, v in params.items()) + ")"


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."
