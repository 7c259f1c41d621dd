"""Episodes in worker processes, results in input order (``craft eval sim|static --jobs N``).

Each worker builds its own context once (grounders, image encoder: whatever ``build`` returns)
and runs ``fn(context, item)`` per item; results come back in the order of ``items`` whatever
order the workers finish in, so a report is byte-identical to the one-process run as long as
``fn`` depends only on its item (every episode builds its own pybullet client from its seeded
spec, and torch runs with a fixed thread count). Workers are *spawned*, never forked: a fork
would copy torch's and OpenBLAS's thread pools in an undefined state.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator, Sequence
from functools import partial
from typing import Any, TypeVar

from ...signals import exit_through_python_on_sigterm

T = TypeVar("T")
R = TypeVar("R")

_CONTEXT: dict[str, Any] = {}


def _init(build: Callable[[], Any]) -> None:
    # ``pool.terminate`` (an error, or the main process stopped by SIGTERM) sends SIGTERM: exit
    # through Python, so the worker's exit hooks (its temporary URDF folder's removal) still run
    exit_through_python_on_sigterm()
    _CONTEXT["value"] = build()


def _call(fn: Callable[[Any, T], R], item: T) -> R:
    return fn(_CONTEXT["value"], item)


def ordered_map(
    fn: Callable[[Any, T], R],
    items: Sequence[T],
    *,
    jobs: int,
    build: Callable[[], Any],
    context: Any = None,
) -> Iterator[R]:
    """``fn(ctx, item)`` for every item, yielded in input order.

    ``jobs`` 1 runs in this process with ``context`` (or ``build()`` if None); more spawns that
    many workers (at most one per item), each with its own ``build()``. ``fn`` and ``build``
    must be picklable (module-level functions or ``functools.partial`` of them).
    """
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    if jobs == 1 or len(items) <= 1:
        ctx = context if context is not None else build()
        for item in items:
            yield fn(ctx, item)
        return
    spawn = multiprocessing.get_context("spawn")
    pool = spawn.Pool(min(jobs, len(items)), initializer=_init, initargs=(build,))
    try:
        yield from pool.imap(partial(_call, fn), items, chunksize=1)
        # Done: let the workers exit on their own, so their exit hooks run (``terminate``, what
        # ``with Pool`` does, kills them and left each worker's temporary folders behind).
        pool.close()
    except BaseException:
        pool.terminate()  # an error, Ctrl-C or an abandoned iterator: stop at once
        raise
    finally:
        pool.join()
