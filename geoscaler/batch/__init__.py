"""``geoscaler batch``: the downsampling job over a library of assets.

:func:`find_assets` finds the assets under IN_DIR, :func:`plan_assets` mirrors the folder tree
under OUT_DIR, :func:`run_asset` runs the whole job of one asset (``prepare`` and
``downsample_and_report``, as ``geoscaler downsample`` does) and :func:`command` runs them on an
engine and writes ``summary.csv``, ``summary.json`` and ``summary.md`` into OUT_DIR.

- Nothing half-written: an asset is written into a staging folder of its own beside its outputs
  (``.geoscaler-batch-*``) and renamed into place when complete, its report last. A worker that
  dies leaves only its staging folder, which the batch removes.
- Engines: ``local``, ``--jobs N`` spawned worker processes with ``cores // N`` torch threads
  each; ``ray``, one Ray task per asset (an optional extra), files through shared paths.
- Ctrl-C: the first stops new assets from starting (running local jobs stop optimising and
  keep their best result, as ``downsample`` does; Ray tasks run to their end); the second
  aborts what runs. The summary is written either way.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from geoscaler.clock import WALL_CLOCK
from geoscaler.errors import GeoscalerError
from geoscaler.io import check_outputs, prepare_folder

from .assets import STAGING_PREFIX, Asset, completed, find_assets, plan_assets, resume_key
from .engines import Interrupts, available_cores, import_ray, run_local, run_ray
from .summary import SUMMARY_FILES, summary_row, total_row, write_summary
from .worker import DONE, FAILED, NOT_RUN, SKIPPED, AssetResult, AssetTask, run_asset

LOCK_NAME = ".geoscaler-batch.lock"

__all__ = [
    "DONE", "FAILED", "NOT_RUN", "SKIPPED", "SUMMARY_FILES", "Asset", "AssetResult", "AssetTask",
    "command", "find_assets", "plan_assets", "run_asset",
]  # fmt: skip


@contextlib.contextmanager
def locked(out_dir: Path) -> Iterator[None]:
    """One batch at a time writes into ``out_dir`` (its stale staging folders are removed)."""
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock
        yield
        return
    path = out_dir / LOCK_NAME
    with open(path, "a+b") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise GeoscalerError(
                f"-o {out_dir}: another geoscaler batch is writing into this folder; wait for "
                "it to end or choose another output folder"
            ) from None
        try:
            yield
        finally:
            path.unlink(missing_ok=True)


def _sweep_stale(out_dir: Path) -> None:
    """Remove the staging folders of a batch that was killed (under the lock: none is ours)."""
    for folder, subfolders, _ in os.walk(out_dir):
        for name in [d for d in subfolders if d.startswith(STAGING_PREFIX)]:
            shutil.rmtree(Path(folder) / name, ignore_errors=True)
            subfolders.remove(name)


def _make_folders(assets: Sequence[Asset], out_dir: Path) -> list[Path]:
    """Create the output folders; returns those that were new, deepest first."""
    created = set()
    for asset in assets:
        folder = asset.output.parent
        while folder != out_dir and not folder.exists() and out_dir in folder.parents:
            created.add(folder)
            folder = folder.parent
        asset.output.parent.mkdir(parents=True, exist_ok=True)
    return sorted(created, key=lambda p: len(p.parts), reverse=True)


def command(args: Any, settings: dict[str, Any]) -> int:
    """``geoscaler batch``: run every asset, write the summary; returns the number of assets
    that failed (at most 125, an exit status). ``settings``: ``geoscaler.cli.job_settings``."""
    in_dir, out_dir = Path(args.in_dir), Path(args.output)
    _check_arguments(args, in_dir, out_dir)
    if args.engine == "ray":
        import_ray()
    key = resume_key(settings, args.format)
    prepare_folder(out_dir, "-o")
    with locked(out_dir):
        summaries = [out_dir / name for name in SUMMARY_FILES]
        _check_no_earlier_batch(args, out_dir, summaries)
        check_outputs(summaries, force=True)
        assets = _plan(in_dir, out_dir, args.format)
        _sweep_stale(out_dir)
        results = _finished_before(assets, key) if args.resume else {}
        todo = [a for a in assets if a.name not in results]
        created = _make_folders(todo, out_dir)
        workers = _workers(args)
        print(
            f"batch: {len(assets)} assets in {in_dir}: {len(todo)} to run, {len(results)} "
            f"finished before (skipped); engine {args.engine}, {workers}"
        )
        start, stopped = WALL_CLOCK.now(), False
        try:
            stopped = _run(todo, settings, key, args, results)
        finally:
            with _ctrl_c_deferred() as interrupted:
                wall = WALL_CLOCK.now() - start
                run = {"engine": args.engine, "workers": workers, "settings": key}
                document, written = _summarise(in_dir, out_dir, assets, todo, results, run, wall)
                _remove_empty(created)
            stopped = stopped or interrupted()
    failed = sum(row["status"] == FAILED for row in document["assets"])
    print(f"total: {document['total']['status']}; wrote {', '.join(map(str, written))}")
    if stopped:
        raise KeyboardInterrupt
    return min(failed, 125)


@contextlib.contextmanager
def _ctrl_c_deferred() -> Iterator[Callable[[], bool]]:
    """Write the summary whole: a Ctrl-C while it is written (the second of two, a moment
    after the first ended the run) is held until it is done; ``interrupted()`` then says
    whether one came. Outside the main thread signals do not reach this code anyway."""
    came: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    previous = signal.signal(signal.SIGINT, lambda signum, frame: came.append(signum))
    try:
        yield lambda: bool(came)
    finally:
        signal.signal(signal.SIGINT, previous)


def _check_arguments(args: Any, in_dir: Path, out_dir: Path) -> None:
    """IN_DIR is a folder, OUT_DIR another; the counts of jobs, CPUs and GPUs are > 0."""
    if not in_dir.is_dir():
        raise GeoscalerError(f"{in_dir}: no such folder; give the folder that holds the assets")
    if out_dir.resolve() == in_dir.resolve():
        raise GeoscalerError(f"-o {out_dir}: is IN_DIR; give the outputs a folder of their own")
    if args.jobs < 1 or args.cpus_per_task <= 0 or args.gpus_per_task <= 0:
        raise GeoscalerError("--jobs, --cpus-per-task and --gpus-per-task: give numbers > 0")


def _check_no_earlier_batch(args: Any, out_dir: Path, summaries: list[Path]) -> None:
    """Refuse an OUT_DIR that holds an earlier batch's summary, unless --resume or --force."""
    if not (args.resume or args.force) and any(p.exists() for p in summaries):
        raise GeoscalerError(
            f"-o {out_dir}: a batch ran into this folder before (it holds summary.json); "
            "pass --resume to go on with it (finished assets are skipped) or --force to "
            "redo every asset"
        )


def _plan(in_dir: Path, out_dir: Path, fmt: str | None) -> list[Asset]:
    """The assets under ``in_dir`` (:func:`plan_assets`); refuses a folder without any."""
    assets = plan_assets(in_dir, out_dir, fmt)
    if not assets:
        raise GeoscalerError(
            f"{in_dir}: no assets found (.glb, .gltf or .obj files, or folders whose "
            'meta.json names one as "entry")'
        )
    return assets


def _finished_before(assets: Sequence[Asset], key: dict[str, Any]) -> dict[str, AssetResult]:
    """SKIPPED results of the assets an earlier batch completed with the same settings."""
    results: dict[str, AssetResult] = {}
    for asset in assets:
        document = completed(asset, key)
        if document is not None:
            results[asset.name] = AssetResult(asset.name, SKIPPED, document)
    return results


def _workers(args: Any) -> str:
    """The engine's workers in words, e.g. ``2 jobs x 4 torch thread(s)``."""
    if args.engine == "ray":
        return f"{args.cpus_per_task:g} CPU per task"
    threads = max(1, available_cores() // args.jobs)
    return f"{args.jobs} job{'s' * (args.jobs > 1)} x {threads} torch thread(s)"


def _summarise(
    in_dir: Path,
    out_dir: Path,
    assets: Sequence[Asset],
    todo: Sequence[Asset],
    results: dict[str, AssetResult],
    run: dict[str, Any],
    wall: float,
) -> tuple[dict[str, Any], list[Path]]:
    """Write the summary files (assets without a result: NOT_RUN); returns the document and
    the files written. ``run``: the engine, workers and settings."""
    for asset in assets:
        results.setdefault(asset.name, AssetResult(asset.name, NOT_RUN))
    rows = [summary_row(a, results[a.name], out_dir) for a in assets]
    ran = sum(results[a.name].status == DONE for a in todo)
    document = {
        "in_dir": str(in_dir),
        "out_dir": str(out_dir),
        "run": {
            **run,
            "wall_seconds": round(wall, 3),
            "assets_per_hour": round(3600 * ran / wall, 2) if wall > 0 else 0.0,
        },
        "assets": rows,
        "total": total_row(rows),
    }
    return document, write_summary(out_dir, document)


def _remove_empty(created: Sequence[Path]) -> None:
    """Remove the output folders this batch created and wrote nothing into (deepest first)."""
    for folder in created:
        with contextlib.suppress(OSError):
            folder.rmdir()  # only if empty: no asset was written there


def _run(
    todo: Sequence[Asset],
    settings: dict[str, Any],
    key: dict[str, Any],
    args: Any,
    results: dict[str, AssetResult],
) -> bool:
    """Run ``todo`` on the engine with a bar over the assets; True if Ctrl-C stopped it."""
    from tqdm import tqdm

    if not todo:
        return False
    tasks = [AssetTask(asset, settings, key, args.evaluation) for asset in todo]
    with tqdm(total=len(tasks), desc="batch", unit="asset", dynamic_ncols=True) as bar:

        def say(line: str) -> None:
            bar.write(line, file=sys.stderr)

        def done(result: AssetResult) -> None:
            results[result.name] = result
            if result.status == FAILED:
                say(f"geoscaler: failed: {result.error}")
            failed = sum(r.status == FAILED for r in results.values())
            bar.set_postfix_str(f"{result.name} {result.status}; {failed} failed", refresh=False)
            bar.update(1)

        if args.engine == "ray":
            interrupts = Interrupts(say, "running Ray tasks finish")
            with interrupts.installed():
                cpus, gpus = args.cpus_per_task, args.gpus_per_task
                run_ray(tasks, done, interrupts, args.ray_address, cpus, gpus)
        else:
            running = "running assets stop optimising and keep their best result"
            interrupts = Interrupts(say, running)
            with interrupts.installed():
                run_local(tasks, args.jobs, done, interrupts)
    return interrupts.stopping
