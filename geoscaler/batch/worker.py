"""One asset's job, as a worker process or Ray task runs it: nothing is left half-written."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from geoscaler.clock import WALL_CLOCK
from geoscaler.errors import GeoscalerError, WriteError
from geoscaler.io import check_outputs
from geoscaler.pipeline.downsampling import prepare
from geoscaler.process import configure_process
from geoscaler.protocol import PROTOCOL_EVALUATION, Evaluation
from geoscaler.report.documents import dumps
from geoscaler.report.runner import downsample_and_report

from .assets import Asset

DONE, SKIPPED, FAILED, NOT_RUN = "done", "skipped", "failed", "not run"


@dataclass
class AssetTask:
    """What a worker needs to run one asset: ``settings`` are the keyword arguments of
    ``prepare`` (``geoscaler.cli.job_settings``), ``key`` what ``--resume`` compares."""

    asset: Asset
    settings: dict[str, Any]
    key: dict[str, Any]
    evaluation: Evaluation = PROTOCOL_EVALUATION
    threads: int | None = None


@dataclass
class AssetResult:
    """How one asset went: ``status`` one of :data:`DONE`, :data:`SKIPPED` (finished by an
    earlier batch), :data:`FAILED` (``error`` says why, on one line) or :data:`NOT_RUN`;
    ``document`` its report; ``seconds`` the job's wall time in its worker."""

    name: str
    status: str
    document: dict[str, Any] | None = None
    error: str | None = None
    seconds: float = 0.0


_stop_requested = False
"""In a worker process: Ctrl-C was pressed while no job ran (see :func:`init_worker`)."""


def _quiet(*_: Any) -> None:
    pass


def run_asset(task: AssetTask) -> AssetResult:
    """Run the whole job of one asset in this process and put its files into place.

    The mesh, its side files and the report are written into a staging folder beside the
    output and renamed into place when all are complete, the report last; the staging folder
    is removed whatever happens. A bad asset returns a failed result with its one-line error.
    """
    start = WALL_CLOCK.now()
    configure_process()  # a Ray worker process did not start from the command line
    if task.threads:
        import torch

        torch.set_num_threads(task.threads)
    asset, force = task.asset, task.settings["force"]
    result, staging = AssetResult(asset.name, FAILED), None
    try:
        if asset.problem is not None:
            raise GeoscalerError(f"{asset.path}: {asset.problem}")
        staging = Path(tempfile.mkdtemp(prefix=asset.staging_prefix, dir=asset.output.parent))
        settings = {**task.settings, "force": False}  # the staging folder is new and empty
        job = prepare(asset.path, staging / asset.output.name, started_at=start, **settings)
        finals = [asset.output.parent / p.relative_to(staging) for p in job.output_files]
        check_outputs([*finals, asset.report], force=force, inputs=job.mesh.source_files)
        if _stop_requested:
            result.status = NOT_RUN
            return result
        _, document = downsample_and_report(job, task.evaluation, progress=False, say=_quiet)
        inputs = dict.fromkeys([asset.path, *job.mesh.source_files])
        document["output"] = str(asset.output)
        document["batch"] = {
            "settings": task.key,
            "inputs": [os.path.relpath(p, asset.path.parent) for p in inputs],
            "outputs": [os.path.relpath(p, asset.output.parent) for p in finals],
            "seconds": round(WALL_CLOCK.now() - start, 3),
            "host": socket.gethostname(),
        }
        staged_report = staging / asset.report.name
        try:
            staged_report.write_text(dumps(document) + "\n", encoding="utf-8")
        except OSError as error:
            raise WriteError(staged_report, error) from error
        staged = [*job.output_files, staged_report]  # the main file, then the report, last
        move_into_place(staged, [*finals, asset.report])
        result.status, result.document = DONE, document
    except WriteError as error:  # named where the user looks for it, not in the staging folder
        moved = error if staging is None else error.moved(staging, asset.output.parent)
        result.error = one_line(str(moved), asset.path)
    except GeoscalerError as error:
        result.error = one_line(str(error), asset.path)
    except Exception as error:  # one bad asset must not stop the batch
        message = f"unexpected {type(error).__name__}: {error} (please report this)"
        result.error = one_line(message, asset.path)
    finally:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)
        result.seconds = WALL_CLOCK.now() - start
    return result


def move_into_place(staged: list[Path], finals: list[Path]) -> None:
    """Rename each staged file to its final path, in order; when one fails, the ones already
    moved are removed again (an asset is there whole or not at all) and WriteError names it."""
    moved: list[Path] = []
    try:
        for source, final in zip(staged, finals, strict=True):
            final.parent.mkdir(parents=True, exist_ok=True)
            os.replace(source, final)
            moved.append(final)
    except OSError as error:
        for path in moved:
            path.unlink(missing_ok=True)
        raise WriteError(finals[len(moved)], error) from error


def one_line(message: str, path: Path) -> str:
    """``message`` on one line, naming ``path``."""
    message = " ".join(message.split())
    return message if str(path) in message else f"{path}: {message}"


def _worker_sigint(signum: int, frame: Any) -> None:
    """A worker's Ctrl-C outside a job (a job has its own: ``stop_on_interrupt``)."""
    global _stop_requested
    if _stop_requested:
        raise KeyboardInterrupt
    _stop_requested = True


def init_worker() -> None:
    """A local worker process's start: Ctrl-C outside a job must not kill it (that would
    break the pool and every job running in it), see :mod:`geoscaler.batch.engines`."""
    signal.signal(signal.SIGINT, _worker_sigint)
