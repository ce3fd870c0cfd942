"""Engines: where the assets' jobs run. ``local``: spawned worker processes on this machine;
``ray``: one Ray task per asset on a Ray cluster (an optional extra)."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from geoscaler.errors import GeoscalerError

from .assets import sweep
from .worker import FAILED, NOT_RUN, AssetResult, AssetTask, init_worker, one_line, run_asset


class Interrupts:
    """The driver's Ctrl-C: the first sets :attr:`stopping` (no new asset starts), the second
    raises KeyboardInterrupt (what runs is aborted)."""

    def __init__(self, say: Callable[[str], None], running: str):
        self.stopping, self.say, self.running = False, say, running

    def __call__(self, signum: int, frame: Any) -> None:
        if self.stopping:
            raise KeyboardInterrupt
        self.stopping = True
        self.say(f"stopping: no new asset starts; {self.running}; Ctrl-C again to abort them")

    @contextlib.contextmanager
    def installed(self) -> Iterator[Interrupts]:
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        previous = signal.signal(signal.SIGINT, self)
        try:
            yield self
        finally:
            signal.signal(signal.SIGINT, previous)


def available_cores() -> int:
    """The CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


DIED = "the worker process died while running it (killed, or out of memory?)"


def run_local(
    tasks: Sequence[AssetTask],
    jobs: int,
    done: Callable[[AssetResult], None],
    interrupts: Interrupts,
) -> None:
    """Run ``tasks`` in ``jobs`` spawned worker processes, ``cores // jobs`` torch threads
    each, calling ``done`` with each result.

    At most ``jobs`` tasks are in flight, so a worker that dies (the pool breaks and every
    running task is lost) points at the tasks that ran: one alone fails; of several, each is
    run again alone, and fails if it breaks its worker again.
    """
    import concurrent.futures as cf
    import multiprocessing
    from concurrent.futures.process import BrokenProcessPool

    threads = max(1, available_cores() // jobs)
    queue = [AssetTask(**{**vars(task), "threads": threads}) for task in tasks]
    suspect: set[str] = set()
    while queue and not interrupts.stopping:
        pool = cf.ProcessPoolExecutor(
            jobs, mp_context=multiprocessing.get_context("spawn"), initializer=init_worker
        )
        running: dict[cf.Future, AssetTask] = {}
        try:
            while running or (queue and not interrupts.stopping):
                while queue and not interrupts.stopping and _room(running, queue[0], jobs, suspect):
                    future = pool.submit(run_asset, queue[0])
                    running[future] = queue.pop(0)
                finished, _ = cf.wait(running, timeout=1.0, return_when=cf.FIRST_COMPLETED)
                for future in finished:
                    done(_outcome(future, running[future]))  # a broken pool raises here
                    del running[future]
        except BrokenProcessPool:
            _stop(pool, running)
            for task in running.values():
                if len(running) == 1 or task.asset.name in suspect:
                    done(AssetResult(task.asset.name, FAILED, error=f"{task.asset.path}: {DIED}"))
                else:
                    suspect.add(task.asset.name)
                    queue.insert(0, task)
            continue
        except BaseException:
            _stop(pool, running)
            raise
        pool.shutdown(wait=True)


def _outcome(future: Any, task: AssetTask) -> AssetResult:
    """The result of a finished future; raises BrokenProcessPool when its worker died."""
    from concurrent.futures.process import BrokenProcessPool

    try:
        return future.result()
    except KeyboardInterrupt:  # the worker's second Ctrl-C
        return AssetResult(task.asset.name, NOT_RUN)
    except BrokenProcessPool:
        raise
    except Exception as error:  # e.g. a result that cannot be sent back
        why = f"unexpected {type(error).__name__} in its worker: {error} (please report this)"
        return AssetResult(task.asset.name, FAILED, error=one_line(why, task.asset.path))


def _room(running: dict, task: AssetTask, jobs: int, suspect: set[str]) -> bool:
    """Whether ``task`` may start now: a suspect runs alone."""
    if not running:
        return True
    if task.asset.name in suspect or any(t.asset.name in suspect for t in running.values()):
        return False
    return len(running) < jobs


def _stop(pool: Any, running: dict) -> None:
    """End the pool's workers now and remove what the running tasks left."""
    # The executor has no public way to stop running work: terminate its processes.
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        process.terminate()
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.join(timeout=30)
    for task in running.values():
        sweep(task.asset)


def import_ray() -> Any:
    """The ``ray`` module, or a GeoscalerError that says how to install it."""
    try:
        import ray
    except ImportError:
        raise GeoscalerError(
            "--engine ray needs Ray, an optional extra: pip install 'geoscaler[ray]' (on every "
            "machine of the cluster); or use --engine local"
        ) from None
    return ray


def run_ray(
    tasks: Sequence[AssetTask],
    done: Callable[[AssetResult], None],
    interrupts: Interrupts,
    address: str | None = None,
    cpus: float = 1.0,
    gpus: float = 1.0,
) -> None:
    """Run each task as one Ray task (``cpus`` CPUs; ``gpus`` GPUs when the job's device is
    CUDA, or auto on a cluster that has GPUs). Uses the running Ray instance, or connects to
    ``address`` (Ray's default when None; ``"local"`` starts one on this machine). Files go
    through the paths the tasks are given: IN_DIR and OUT_DIR must be shared by the workers.
    At most as many tasks are submitted as the cluster can run at once, so that a Ctrl-C stops
    what has not started.
    """
    ray = import_ray()
    started = not ray.is_initialized()
    if started:
        import logging

        ray.init(address=address, logging_level=logging.WARNING, log_to_driver=False)
    try:
        use_gpus, capacity = _ray_slots(ray.cluster_resources(), tasks, cpus, gpus)
        remote = ray.remote(run_asset).options(
            num_cpus=cpus, num_gpus=gpus if use_gpus else 0, max_retries=1
        )
        queue = [AssetTask(**{**vars(t), "threads": max(1, round(cpus))}) for t in tasks]
        _run_queue(ray, remote, queue, capacity, done, interrupts)
    finally:
        if started:
            ray.shutdown()


def _ray_slots(
    resources: dict[str, float], tasks: Sequence[AssetTask], cpus: float, gpus: float
) -> tuple[bool, int]:
    """Whether the tasks ask for GPUs, and how many of them the cluster runs at once."""
    device = tasks[0].settings["options"].device if tasks else "cpu"
    use_gpus = device == "cuda" or (device == "auto" and resources.get("GPU", 0) > 0)
    if device == "cuda" and resources.get("GPU", 0) < gpus:
        raise GeoscalerError("--device cuda: the Ray cluster has no GPU; use --device auto")
    limits = [resources.get("CPU", 1) / cpus] + ([resources["GPU"] / gpus] if use_gpus else [])
    return use_gpus, max(1, int(min(limits)))


def _run_queue(
    ray: Any,
    remote: Any,
    queue: list[AssetTask],
    capacity: int,
    done: Callable[[AssetResult], None],
    interrupts: Interrupts,
) -> None:
    """Keep up to ``capacity`` tasks running until the queue is done or a Ctrl-C stops it;
    on an error or a second Ctrl-C, cancel the running ones."""
    running: dict[Any, AssetTask] = {}
    try:
        while running or (queue and not interrupts.stopping):
            while queue and not interrupts.stopping and len(running) < capacity:
                task = queue.pop(0)
                running[remote.remote(task)] = task
            ready, _ = ray.wait(list(running), num_returns=1, timeout=1.0)
            for ref in ready:
                _ray_result(ray, ref, running.pop(ref), done)
    except BaseException:
        _cancel_ray(ray, running)
        raise


def _ray_result(ray: Any, ref: Any, task: AssetTask, done: Callable[[AssetResult], None]) -> None:
    """Pass on the result of a finished Ray task; a task Ray lost (its worker or node) FAILED."""
    try:
        done(ray.get(ref))
    except ray.exceptions.RayError as error:  # its worker died, its node was lost
        sweep(task.asset)
        text = str(error).strip().splitlines()
        why = one_line(f"Ray: {type(error).__name__}: {text[0]}", task.asset.path)
        done(AssetResult(task.asset.name, FAILED, error=why))


def _cancel_ray(ray: Any, running: dict[Any, AssetTask]) -> None:
    """Cancel the running Ray tasks, wait for them (30 s at most), remove what they left."""
    for ref in running:
        ray.cancel(ref, force=True)
    with contextlib.suppress(Exception):
        ray.wait(list(running), num_returns=len(running), timeout=30)
    for task in running.values():
        sweep(task.asset)
