"""Analyses and figures off the station's process: one worker process, a bounded queue in
front of it and a cache of its answers.

Rendering a figure is seconds of pure-Python matplotlib holding the interpreter's lock;
in a thread of the station it delays the event loop, and with it the flight state sent
to the pilot. In a separate process it costs a core at most, never the loop's time.

- The worker is a spawned process (a fork of a threaded server is unsafe) at a lower
  scheduling priority (nice 10), started by the first request and stopped after
  `idle_s` without one, so an idle Pi keeps its memory; it ends itself when the station
  is gone. A worker that died (out of memory) is replaced by the next request.
- At most `max_pending` jobs are accepted at a time (running or queued, over every
  client); one more is refused with `AnalysisBusy` (503) at once, not queued.
- Answers are cached by what decides them (`key`): the files' size and modification
  time and the parsed parameters, never the raw query, so junk added to a URL finds the
  cached answer. A request equal to one still running waits for that one's answer.
  Errors are answers too: the same files give the same error.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fpv_station.server.errors import Unavailable

if TYPE_CHECKING:
    from concurrent.futures import ProcessPoolExecutor

log = logging.getLogger(__name__)

MAX_PENDING = 4
CACHE_ENTRIES = 32  # PNGs of ~100-200 kB and JSON tables: a few MB at most
IDLE_S = 120.0


class AnalysisBusy(Unavailable):
    """Too many analyses asked at once (503): try again when the running ones are done."""


@dataclass
class WorkerStats:
    """What the worker did, for tests and /api/health-like reports."""

    jobs: int = 0  # run in the worker process
    cache_hits: int = 0  # answered from the cache
    joined: int = 0  # answered by a job already running for the same key
    refused: int = 0  # refused with AnalysisBusy
    peak_pending: int = 0  # most jobs accepted at once
    processes: int = 0  # worker processes started


@dataclass
class _Answer:
    value: Any = None
    error: BaseException | None = None

    def get(self) -> Any:
        if self.error is not None:
            raise self.error
        return self.value


@dataclass
class AnalysisWorker:
    max_pending: int = MAX_PENDING
    cache_entries: int = CACHE_ENTRIES
    idle_s: float = IDLE_S
    stats: WorkerStats = field(default_factory=WorkerStats)
    _pool: ProcessPoolExecutor | None = None
    _pending: int = 0
    _running: dict[Hashable, asyncio.Task[_Answer]] = field(default_factory=dict)
    _cache: OrderedDict[Hashable, _Answer] = field(default_factory=OrderedDict)
    _idle: asyncio.TimerHandle | None = None
    _closed: bool = False

    async def run(self, key: Hashable, fn: Callable[..., Any], *args: Any) -> Any:
        """`fn(*args)` in the worker process (a picklable top-level function), or the
        cached answer for `key`; AnalysisBusy when `max_pending` jobs are in hand."""
        if key in self._cache:
            self._cache.move_to_end(key)
            self.stats.cache_hits += 1
            return self._cache[key].get()
        job = self._running.get(key)
        if job is not None:
            self.stats.joined += 1
        else:
            if self._closed:
                raise AnalysisBusy("The station is stopping; analyses are not taken now.")
            if self._pending >= self.max_pending:
                self.stats.refused += 1
                raise AnalysisBusy(
                    f"{self._pending} analyses are being made for other requests; "
                    "try again in a few seconds."
                )
            self._pending += 1  # counted now: the next request must see it
            self.stats.peak_pending = max(self.stats.peak_pending, self._pending)
            if self._idle is not None:
                self._idle.cancel()
                self._idle = None
            # The job runs to its end even if the client that asked leaves: others may
            # be waiting for it, and its answer goes into the cache.
            job = asyncio.get_running_loop().create_task(self._job(key, fn, args))
            self._running[key] = job
        return (await asyncio.shield(job)).get()

    async def _job(self, key: Hashable, fn: Callable[..., Any], args: tuple) -> _Answer:
        try:
            answer = await self._submit(fn, args)
        finally:
            self._pending -= 1
            del self._running[key]
            if self._pending == 0 and not self._closed:
                loop = asyncio.get_running_loop()
                self._idle = loop.call_later(self.idle_s, self._stop_pool)
        if answer is None:  # the worker died: not an answer to keep
            return _Answer(error=AnalysisBusy("The analysis worker stopped; try again."))
        self._cache[key] = answer
        while len(self._cache) > self.cache_entries:
            self._cache.popitem(last=False)
        return answer

    async def _submit(self, fn: Callable[..., Any], args: tuple) -> _Answer | None:
        # Imported here: a station nobody asks for an analysis never loads them.
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        from concurrent.futures.process import BrokenProcessPool

        if self._pool is None:
            ctx = multiprocessing.get_context("spawn")
            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=worker_init)
            self.stats.processes += 1
        self.stats.jobs += 1
        try:
            return _Answer(value=await asyncio.wrap_future(self._pool.submit(fn, *args)))
        except BrokenProcessPool:
            log.error("the analysis worker process died; the next request starts another")
            self._stop_pool()
            return None
        except Exception as exc:  # the job's own error (AnalysisError ...): an answer
            return _Answer(error=exc)

    def _stop_pool(self) -> None:
        pool, self._pool, self._idle = self._pool, None, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        """Stop the worker (the station is stopping); running requests get AnalysisBusy."""
        self._closed = True
        if self._idle is not None:
            self._idle.cancel()
        self._stop_pool()


# ---------------------------------------------------------------- in the worker process

WORKER_NICE = 10
PARENT_CHECK_S = 2.0


def worker_init() -> None:
    """The worker yields the cores to the station (on a busy Pi the scheduler gives the
    flight state's process the time first, and the figures wait), and ends with it: a
    station killed outright (SIGKILL, the OOM killer) cannot stop its pool, and an
    orphaned worker would hold its memory for good."""
    os.nice(WORKER_NICE)
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_CHECK_S)
        os._exit(0)

    threading.Thread(target=watch, name="parent watch", daemon=True).start()


Stamp = tuple[str, int, int]  # path, mtime_ns, size


@dataclass(frozen=True)
class AnalysisJob:
    """Everything that decides an analysis' answer: the cache key and the worker's input."""

    files: tuple[tuple[str, Stamp, Stamp | None], ...]  # (session id, data, session.json)
    task: str
    reference: tuple[float, float] | None
    scene: str | None
    params: Any  # analysis.tasks.TaskParams (frozen, hashable)
    flight: int | None
    plot: str | None  # None: the table


def run_job(job: AnalysisJob) -> dict | bytes:
    """In the worker: the table (the CLI's TABLE.json) or one figure as PNG."""
    an = _analysis(replace(job, plot=None))
    if job.plot is not None:
        return an.plot(job.plot)
    return an.to_dict()


@functools.lru_cache(maxsize=4)
def _analysis(job: AnalysisJob):  # -> analysis.report.Analysis
    # The figures of one table come one request each: their analysis is made once.
    from fpv_station.analysis.field_layout import load_field_layout
    from fpv_station.analysis.report import analyze_tracks
    from fpv_station.analysis.track import load_track

    # The session folder (its files sit at its top), read as the CLI and the score at
    # disarm read it: its session.json's measured vehicle clock places the samples.
    tracks = [load_track(Path(data).parent, label=sid) for sid, (data, _, _), _ in job.files]
    field_ = load_field_layout(job.scene)
    return analyze_tracks(tracks, job.task, job.reference, field_, job.params, job.flight)
