"""How a running optimisation talks to the outside: the :class:`ProgressEvent` reports it
sends (the CLI's progress bars, the app's live state) and the :class:`Controller` that pauses,
resumes or stops it from another thread."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import torch


@dataclass
class ProgressEvent:
    """A report from the loop.

    Attributes:
        phase: ``"caching"`` (before the first step), ``"step"``, ``"baselines"`` (the
            filters scored on the frozen validation sets), ``"validation"`` or ``"done"``.
        step: steps completed.
        total_steps: the step limit.
        elapsed: seconds since the loop started.
        loss: the latest training loss (nan before the first step).
        validation_psnr: PSNR-fg on Q of this validation (``"validation"`` events).
        best_psnr: Q's PSNR-fg of the best candidate so far.
        done / total: views cached of all the loop will cache (training and validation).
        scores: set name -> PSNR-fg of this validation (``"validation"`` events).
        baselines: filter name -> its scores per set (``"baselines"`` events).
        candidate: returns the current ``(textures, uvs)``, detached, on request: linear
            textures and UVs (None when the model keeps the mesh's own).
    """

    phase: str
    step: int
    total_steps: int
    elapsed: float
    loss: float = math.nan
    validation_psnr: float | None = None
    best_psnr: float = -math.inf
    done: int = 0
    total: int = 0
    scores: dict[str, float] = field(default_factory=dict)
    baselines: dict[str, dict[str, float]] = field(default_factory=dict)
    candidate: Callable[[], tuple[list[torch.Tensor | None], torch.Tensor | None]] | None = field(
        default=None, repr=False
    )


class Controller:
    """Pause, resume and stop a running loop from another thread."""

    def __init__(self):
        self._running = threading.Event()
        self._running.set()
        self._stop = threading.Event()

    def pause(self) -> None:
        self._running.clear()

    def resume(self) -> None:
        self._running.set()

    def stop(self) -> None:
        self._stop.set()
        self._running.set()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    @property
    def paused(self) -> bool:
        return not self._running.is_set()

    def wait_while_paused(self) -> None:
        self._running.wait()
