"""Work that must not hold up a command's exit: a status written on the way out of a run that was
interrupted or failed, to storage that may itself be what failed (a frozen endpoint)."""

from __future__ import annotations

import threading
from collections.abc import Callable

EXIT_BUDGET_S = 3.0  # what Ctrl-C or SIGTERM may still spend on writing before the command ends


def run_within(actions: list[Callable[[], object]], seconds: float = EXIT_BUDGET_S) -> bool:
    """Run the actions side by side and wait for them at most `seconds`; True if all finished and
    none failed. What is still running is abandoned (daemon threads die with the process)."""
    failed: list[BaseException] = []

    def attempt(action: Callable[[], object]) -> None:
        try:
            action()
        except BaseException as e:
            failed.append(e)

    threads = [threading.Thread(target=attempt, args=(a,), daemon=True) for a in actions]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=max(0.0, seconds))
    return not failed and not any(t.is_alive() for t in threads)
