"""Running a campaign's scenarios: here (``jobs=1``), on every local core (processes), or on
a Dask cluster (``dask=ADDRESS`` or ``"local"``). Results come back as each scenario
finishes, in any order; :func:`run_campaign` returns them in the campaign's order.

A scenario that fails is a failed :class:`~fpgalink.campaign.scenario.Result`, never the end
of the campaign; so is a worker process that dies under one (only that scenario is lost,
and its worker started again). A scenario is deterministic (emulated time, seeded), so
where it ran does not change its figures: a campaign run here, on 2 processes or on a
cluster gives the same table.
"""

from __future__ import annotations

import collections
import concurrent.futures
import contextlib
import importlib
import multiprocessing
import os
import signal
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

from fpgalink.campaign.recording import recording_name
from fpgalink.campaign.scenario import Result, run_scenario
from fpgalink.campaign.spec import (
    Campaign,
    CampaignError,
    Scenario,
    check_installed,
    importable,
)
from fpgalink.recording import DirectoryLock, partial_path

__all__ = ["DASK_MISSING", "check_runnable", "default_jobs", "iter_results", "recording_paths",
           "run_campaign"]

_T = TypeVar("_T")

DASK_MISSING = ("--dask needs dask.distributed: pip install 'fpgalink[campaign]' (or "
                "'dask[distributed]')")


def default_jobs() -> int:
    """Every core this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def run_campaign(campaign: Campaign, *, jobs: int | None = None, dask: str | None = None,
                 on_result: Callable[[Result], None] | None = None,
                 mcap_dir: str | Path | None = None) -> list[Result]:
    """Every scenario of ``campaign``; ``on_result`` is called as each finishes. The
    scenarios that record (``mcap``) write their MCAP files into ``mcap_dir``, replacing
    what is there under their names; one campaign at a time writes there
    (:class:`~fpgalink.recording.OutputBusy` while another, in any process, does)."""
    results = []
    lock = (DirectoryLock(Path(mcap_dir)) if mcap_dir is not None and
            any(s.mcap for s in campaign.scenarios) else contextlib.nullcontext())
    with lock:
        for result in iter_results(campaign.scenarios, jobs=jobs, dask=dask,
                                   mcap_dir=mcap_dir):
            if on_result is not None:
                on_result(result)
            results.append(result)
    return sorted(results, key=lambda r: r.index)


def iter_results(scenarios: Sequence[Scenario], *, jobs: int | None = None,
                 dask: str | None = None, mcap_dir: str | Path | None = None
                 ) -> Iterator[Result]:
    check_runnable(scenarios, dask=dask)  # before the first scenario, not in each one
    paths = recording_paths(scenarios, mcap_dir)
    # A file there older than this run is an earlier run's, not one a lost worker began.
    began = time.time()
    if dask is not None:
        yield from _on_dask(scenarios, paths, dask, jobs, began)
        return
    jobs = default_jobs() if jobs is None else jobs
    if jobs < 1:
        raise CampaignError(f"jobs must be at least 1, got {jobs}")
    if jobs == 1 or len(scenarios) == 1:
        for scenario in scenarios:
            yield run_scenario(scenario, paths[scenario.index])
        return
    yield from _on_processes(scenarios, paths, min(jobs, len(scenarios)), began)


def check_runnable(scenarios: Sequence[Scenario], *, dask: str | None = None,
                   where: str = "campaign") -> None:
    """:class:`CampaignError` (one line) if what the run needs is not installed here: the
    extras of the scenarios' bodies and, for ``dask``, ``dask.distributed``."""
    check_installed(scenarios, where)
    if dask is not None and not importable("dask.distributed"):
        raise CampaignError(DASK_MISSING)


def recording_paths(scenarios: Sequence[Scenario], mcap_dir: str | Path | None
                    ) -> dict[int, str | None]:
    """Each scenario's MCAP file (``None``: not recorded), by index. Absolute, so a worker
    writes where it was meant to whatever its working directory; on a cluster that is the
    same path on each worker's own filesystem (docs/campaigns.md)."""
    recorded = [s for s in scenarios if s.mcap]
    if recorded and mcap_dir is None:
        first = recorded[0]
        raise CampaignError(f"scenario {first.index} ({first.name}) records MCAP (mcap = "
                            "true): give the directory for the recordings (mcap_dir)")
    digits = len(str(max((s.index for s in scenarios), default=0)))
    where = Path(os.path.abspath(mcap_dir)) if mcap_dir is not None else None
    return {s.index: str(where / recording_name(s, digits)) if s.mcap and where else None
            for s in scenarios}


def _worker_started() -> None:
    # Ctrl-C reaches the whole process group: the parent stops the campaign and ends its
    # workers; a worker that died of it on its own would print a traceback and look like a
    # scenario that killed it. Ignoring it discards one held since the worker's start
    # (:func:`_submit`), then it is let through.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _pool(jobs: int, context: Any) -> concurrent.futures.ProcessPoolExecutor:
    return concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context,
                                                  initializer=_worker_started)


def _submit(pool: concurrent.futures.ProcessPoolExecutor, work: Callable[..., _T],
            *args: Any) -> concurrent.futures.Future[_T]:
    """``pool.submit(work, *args)``. A pool's worker starts at its first submit, here, with
    SIGINT blocked in this thread: the mask is inherited across fork and exec, so a Ctrl-C
    during the worker's start-up waits in it until its initializer ignores it. Blocked, not
    ignored: ignoring is process-wide, so a Ctrl-C that came while a worker started was
    lost to the campaign itself, which ran on. Here it waits, and is taken when this
    returns."""
    if not hasattr(signal, "pthread_sigmask"):  # no process groups to signal (Windows)
        return pool.submit(work, *args)
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        return pool.submit(work, *args)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _stop(pool: concurrent.futures.ProcessPoolExecutor) -> None:
    """End the workers now, running scenarios and all (Python 3.14 has
    ``kill_workers()``; before it, the pool's own process table)."""
    processes = getattr(pool, "_processes", None) or {}
    for process in list(processes.values()):
        process.kill()
    pool.shutdown(wait=False, cancel_futures=True)


def _on_processes(scenarios: Sequence[Scenario], paths: dict[int, str | None], jobs: int,
                  began: float) -> Iterator[Result]:
    """``jobs`` one-worker pools, each given the next scenario as it finishes one: a worker
    that dies (killed, out of memory) costs exactly the scenario it was running, and only
    its own pool is started again; the others run on."""
    # spawn, not fork: a fresh interpreter per worker on every platform, and no copy of an
    # event loop, threads or open files from the parent.
    context = multiprocessing.get_context("spawn")
    pending = collections.deque(scenarios)
    pools = [_pool(1, context) for _ in range(jobs)]
    running: dict[concurrent.futures.Future[Result], tuple[int, Scenario]] = {}

    def start(slot: int) -> None:
        if pending:
            scenario = pending.popleft()
            future = _submit(pools[slot], run_scenario, scenario, paths[scenario.index])
            running[future] = (slot, scenario)

    try:
        for slot in range(jobs):
            start(slot)
        while running:
            done, _ = concurrent.futures.wait(
                running, return_when=concurrent.futures.FIRST_COMPLETED)
            for future in done:
                slot, scenario = running.pop(future)
                try:
                    result = future.result()
                except concurrent.futures.process.BrokenProcessPool:
                    result = _lost(scenario, paths[scenario.index],
                                   "its worker process died (killed, or out of memory)",
                                   began)
                    pools[slot].shutdown(wait=False)
                    pools[slot] = _pool(1, context)
                start(slot)
                yield result
        for pool in pools:
            pool.shutdown()
    except BaseException:  # interrupted, or the consumer stopped: no worker left behind
        for pool in pools:
            _stop(pool)
        raise


def _lost(scenario: Scenario, mcap: str | None, why: str, began: float) -> Result:
    """A scenario whose worker never returned: failed, and its recording, if it asked for
    one, said unfinished: what was written up to the death is in ``INDEX-NAME.mcap.partial``
    (where this machine sees it; on a cluster, on the worker's machine), readable without
    its summary."""
    if mcap is None:
        return Result(scenario.index, scenario.name, "failed", {}, why, grid=scenario.grid)
    partial = str(partial_path(Path(mcap)))
    begun = _written_since(partial, began)
    return Result(scenario.index, scenario.name, "failed", {}, why, grid=scenario.grid,
                  mcap=partial if begun else None,
                  mcap_error=f"not finished: {why}" + (
                      f"; what it recorded is in {partial}" if begun else ""))


def _written_since(path: str, began: float) -> bool:
    try:
        return os.path.getmtime(path) >= began
    except OSError:
        return False


def _on_dask(scenarios: Sequence[Scenario], paths: dict[int, str | None], address: str,
             jobs: int | None, began: float) -> Iterator[Result]:
    try:
        # dask.distributed is untyped: held as Any.
        distributed: Any = importlib.import_module("dask.distributed")
    except ImportError:
        raise CampaignError(DASK_MISSING) from None
    Client, LocalCluster, as_completed = (distributed.Client, distributed.LocalCluster,
                                          distributed.as_completed)
    cluster = None
    if address == "local":
        # Processes, one thread each: a scenario holds the GIL the whole time it runs.
        cluster = LocalCluster(n_workers=jobs or default_jobs(), threads_per_worker=1,
                               processes=True, dashboard_address=None)
        client = Client(cluster)
    else:
        try:
            client = Client(address, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise CampaignError(f"--dask {address}: no scheduler there ({exc})") from None
    try:
        futures = {client.submit(run_scenario, s, paths[s.index], pure=False): s
                   for s in scenarios}
        for future, outcome in as_completed(futures, with_results=True, raise_errors=False):
            scenario = futures[future]
            if isinstance(outcome, Result):
                yield outcome
            else:  # the worker died or the scheduler gave up on the task
                yield _lost(scenario, paths[scenario.index],
                            f"dask: {type(outcome).__name__}: {outcome}".splitlines()[0],
                            began)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
