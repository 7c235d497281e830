"""Helper processes (joblib workers, a queue manager) that end with the command that started them.

A command stopped with Ctrl-C must end in one line, and a command killed outright (``kill
-9``, an out-of-memory kill) must not leave its workers behind, each holding a simulation's
memory. Every helper process therefore runs :func:`helper_process_setup` first: it ignores
SIGINT (the terminal sends it to the whole process group; the command itself handles it and
stops its workers) and starts a watchdog thread that ends the process as soon as its parent
is gone.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Iterable, Iterator
from typing import Any

__all__ = [
    "PARENT_POLL_SECONDS",
    "helper_process_setup",
    "run_in_workers",
    "sigint_blocked",
    "start_manager",
]

PARENT_POLL_SECONDS = 0.5
"""How often a helper process checks that its parent is alive [s]."""


def _watch_parent(parent: int) -> None:
    while True:
        time.sleep(PARENT_POLL_SECONDS)
        if os.getppid() != parent:  # the parent died and this process was re-parented
            os._exit(1)


def helper_process_setup() -> None:
    """Make this process a helper: Ctrl-C is left to the parent, and it dies with the parent."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # Started with SIGINT blocked (see run_in_workers): a Ctrl-C pending since then is dropped.
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    parent = os.getppid()
    if parent <= 1:  # already orphaned before this ran
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent,), name="watch-parent", daemon=True).start()


@contextlib.contextmanager
def sigint_blocked() -> Iterator[None]:
    """Hold back Ctrl-C while helper processes are started; it arrives when the block ends.

    A child inherits the signal mask, so a helper starts with SIGINT blocked until
    :func:`helper_process_setup` ignores it: a Ctrl-C during its imports cannot print a
    traceback from the helper. The parent gets its KeyboardInterrupt as the block ends.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    # The standard library's resource tracker, started on first use, unblocks SIGINT after it
    # started itself (instead of restoring the mask): start it before the mask is set.
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def run_in_workers(n_jobs: int, tasks: Iterable) -> Iterator:
    """Run joblib ``delayed`` tasks in ``n_jobs`` helper processes; results as they finish."""
    from joblib import Parallel

    parallel = Parallel(
        n_jobs=n_jobs, return_as="generator_unordered", initializer=helper_process_setup
    )
    with sigint_blocked():  # the workers start (and the first tasks go out) in this call
        return parallel(tasks)


def start_manager() -> Any:
    """A started ``multiprocessing`` manager (shared queues) running as a helper process.

    The caller shuts it down (``manager.shutdown()``).
    """
    from multiprocessing.managers import SyncManager

    manager = SyncManager()
    with sigint_blocked():
        manager.start(helper_process_setup)
    return manager
