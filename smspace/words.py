"""Errors in the words of the caller: a command's message names its flags (`pass --overwrite`,
`smtrain fit --resume RUN`); raised to Python, the same message names the argument to pass
(`overwrite=True`, `smspace.resume(RUN)`), so that a notebook user is never told about a flag
they have no way to give."""

from __future__ import annotations

import functools
import re
from collections.abc import Callable
from typing import Any, TypeVar

from smspace.common.errors import SmspaceError

F = TypeVar("F", bound=Callable[..., Any])

FLAG = re.compile(r"(?:\bsm(?:train|gen) \w+ )?--([a-z][a-z0-9-]*)(?: ([A-Z_]{3,}|[\w./:@+-]*/[\w./:@+-]*))?")


def _argument_names() -> dict[str, str]:
    """{flag: argument} where they differ in more than dashes (`--nh`: n_h)."""
    from smspace.train.config import flag_fields

    return {f.metadata["flag"].lstrip("-"): f.name for f in flag_fields() if f.metadata["flag"]}


def in_python_words(message: str) -> str:
    names = _argument_names()

    def word(match: re.Match[str]) -> str:
        flag, value = match[1], match[2]
        if flag == "resume":
            return f"smspace.resume({value!r})" if value and not value.isupper() else "smspace.resume(run)"
        if flag == "overwrite":
            return "overwrite=True" + (f" {value}" if value else "")
        name = names.get(flag, flag.replace("-", "_"))
        return f"{name}={value!r}" if value and not value.isupper() else f"{name}=" if value else name

    return FLAG.sub(word, message).replace("pass smspace.resume", "call smspace.resume")


def python_errors(function: F) -> F:
    """`function`'s SmspaceErrors, reworded for a Python caller; the cause stays chained."""

    @functools.wraps(function)
    def worded(*args: Any, **kwargs: Any) -> Any:
        try:
            return function(*args, **kwargs)
        except SmspaceError as e:
            reworded = in_python_words(str(e))
            if reworded == str(e):
                raise
            raise SmspaceError(reworded) from e

    return worded  # type: ignore[return-value]
