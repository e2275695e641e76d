"""
The campaign's Dask pool: a local cluster of every core or an existing scheduler.

See docs/campaign.md. The campaign runs its jobs on it and the studies and ``make reproduce`` map
their cases over it with :func:`pool_map`. :class:`WallTime` times the campaign, the studies and
``make reproduce`` (docs/commands.md).
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass
import logging
import math
from multiprocessing import resource_tracker
import os
import signal
import threading
import time
from typing import Callable, Dict, Iterable, Optional, Sequence

from im_common.cli import logger

_log = logger('campaign')


def one_line(exc: BaseException) -> str:
    """Format an exception as one line (its type and text), for a row or an error message."""
    text = ' '.join(str(exc).split())
    return f'{type(exc).__name__}: {text}'[:300]


@dataclass
class Pool:
    """
    A Dask client on a local cluster of ``workers`` single-threaded processes, or on a scheduler.

    The scheduler is an existing one at ``address``. ``map`` yields (index, result) as they finish.
    """

    workers: Optional[int] = None
    address: Optional[str] = None

    def __enter__(self):
        from distributed import Client, LocalCluster   # heavy: Dask, only when a pool starts
        for name in ('distributed', 'distributed.scheduler', 'distributed.worker',
                     'distributed.nanny', 'distributed.core', 'distributed.http.proxy'):
            logging.getLogger(name).setLevel(logging.ERROR)
        t0 = time.perf_counter()
        if self.address:
            try:
                self.client = Client(self.address, timeout='10s')
            except (OSError, TimeoutError) as exc:
                raise ConnectionError(f'--address {self.address}: no Dask scheduler there '
                                      f'({one_line(exc)})') from None
            self.cluster = None
        else:
            n = self.workers or os.cpu_count() or 1
            with _sigint_held() as interrupted:     # the workers inherit it: Ctrl-C is ours
                self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                            dashboard_address=':0', silence_logs=logging.ERROR)
            if interrupted:                 # Ctrl-C while it started: stop now, as later
                self.client = None
                self.__exit__(KeyboardInterrupt, None, None)
                raise KeyboardInterrupt
            self.client = Client(self.cluster)
        self.n_workers = len(self.client.scheduler_info().get('workers', {})) or 1
        self.startup_s = time.perf_counter() - t0
        return self

    def __exit__(self, *exc):
        if exc[0] is not None and issubclass(exc[0], KeyboardInterrupt):
            # interrupted: the campaign says so in one line; the scheduler's complaints about
            # the workers and the data it loses as the cluster closes are not news to the user
            for name in _DASK_LOGGERS:
                logging.getLogger(name).setLevel(logging.CRITICAL + 1)
            with contextlib.suppress(Exception):        # and in the worker processes
                if self.client is not None:
                    self.client.run(_quiet_logs)
        with contextlib.suppress(Exception):
            if self.client is not None:
                self.client.close()
        if self.cluster is not None:
            with contextlib.suppress(Exception):
                self.cluster.close()

    def map(self, fn: Callable, items: Sequence, *args) -> Iterable:  # noqa: A003 (Pool.map)
        from distributed import as_completed   # heavy: Dask, only when a pool runs
        shared = [self.client.scatter(a, broadcast=True) for a in args]
        futures = {self.client.submit(fn, item, *shared, pure=False): i
                   for i, item in enumerate(items)}
        try:
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
        finally:
            for fut in futures:
                fut.cancel()


_DASK_LOGGERS = ('distributed', 'distributed.scheduler', 'distributed.worker',
                 'distributed.nanny', 'distributed.core', 'distributed.client')


def _quiet_logs() -> None:
    """Silence Dask's loggers in this process (a worker's, while an interrupted pool closes)."""
    for name in _DASK_LOGGERS:
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


@contextlib.contextmanager
def _sigint_held():
    """
    Hold SIGINT while the local cluster starts its worker processes; yield a list it marks.

    Ctrl-C in a terminal signals the whole process group. The workers are started with SIGINT
    blocked (a thread's signal mask is inherited by the threads it starts and the processes they
    spawn, across exec), so they never die with a KeyboardInterrupt traceback each: the campaign
    (the main process) takes the signal, closes the cluster and prints its one line. A Ctrl-C that
    arrives during start-up is kept, not lost: the caller checks the list once the cluster is up
    and stops then.
    """
    got: list = []
    if threading.current_thread() is not threading.main_thread():
        yield got
        return
    # multiprocessing's resource tracker, when the first worker's start starts it, unblocks
    # SIGINT in the starting thread once it has spawned (resource_tracker.ensure_running): start
    # it here, so that the workers spawned after it keep SIGINT blocked
    resource_tracker.ensure_running()
    old = signal.signal(signal.SIGINT, lambda *_: got.append(signal.SIGINT))
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield got
    finally:
        # a SIGINT pending for this thread is delivered here, to the handler that keeps it
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        signal.signal(signal.SIGINT, old)


def _call(item, fn):
    return fn(item)


def pool_map(fn: Callable, items: Sequence, workers: Optional[int] = None,
             address: Optional[str] = None, label: str = '', progress: bool = True) -> list:
    """
    Compute ``[fn(x) for x in items]`` on the campaign pool, in order.

    Used by ``make reproduce`` and the studies.

    ``fn`` must be importable by the workers (a module-level function).
    """
    results: list = [None] * len(items)
    if not items:
        return results
    with Pool(workers, address) as pool:
        t0 = time.perf_counter()
        for done, (i, r) in enumerate(pool.map(_call, items, fn), 1):
            results[i] = r
            if progress:
                log_progress(label or 'pool', done, len(items), 0, time.perf_counter() - t0)
    return results


class WallTime:
    """
    The wall time of a command and of its parts, and whether the real plant runs compiled.

    Started when made; :meth:`part` times a part (a ``with`` block; a part timed twice adds up).
    :meth:`figures` gives what the campaign, the studies and ``make reproduce`` write beside
    their results (docs/commands.md): ``wall_s`` (from the start), ``wall_parts_s`` and
    ``real_plant_kernel`` (:attr:`im_plant.real_plant.RealPlant.use_kernel` in this process:
    False with ``IM_REAL_PLANT_KERNEL=0`` or without numba, docs/plant.md §9). They are the only
    figures there that differ from one run of a command to the next; :func:`wall_line` prints
    them.
    """

    def __init__(self):
        self.t0 = time.perf_counter()
        self.parts: Dict[str, float] = {}

    @contextlib.contextmanager
    def part(self, name: str):
        """Time the ``with`` block as the part ``name``."""
        t = time.perf_counter()
        try:
            yield
        finally:
            self.parts[name] = self.parts.get(name, 0.0) + time.perf_counter() - t

    def figures(self) -> dict:
        """Return ``wall_s`` (so far), ``wall_parts_s`` and ``real_plant_kernel``."""
        from im_plant.real_plant import RealPlant  # heavy: numba, only at the command's end
        return {'wall_s': time.perf_counter() - self.t0, 'wall_parts_s': dict(self.parts),
                'real_plant_kernel': bool(RealPlant.use_kernel)}


def wall_line(figures: dict) -> str:
    """Return the line a command prints at its end from :meth:`WallTime.figures`."""
    parts = ', '.join(f'{k} {v:.1f} s' for k, v in figures.get('wall_parts_s', {}).items())
    how = ('compiled (numba)' if figures['real_plant_kernel']
           else 'pure Python (IM_REAL_PLANT_KERNEL=0 or no numba)')
    return (f"wall time {figures['wall_s']:.1f} s" + (f' ({parts})' if parts else '')
            + f'; real plant {how}')


def log_progress(label: str, done: int, total: int, failed: int, elapsed: float) -> None:
    rate = done / elapsed if elapsed > 0 else 0.0
    eta = (total - done) / rate if rate > 0 else float('nan')
    eta_s = f'{int(eta // 60)}m{int(eta % 60):02d}s' if math.isfinite(eta) else '?'
    _log(f'{label}: {done}/{total} runs, {rate:.2f} runs/s, ETA {eta_s}'
         + (f', {failed} failed' if failed else ''))
