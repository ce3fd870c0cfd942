"""What the terminal shows while a job runs: tqdm progress bars, and Ctrl-C handling."""

from __future__ import annotations

import contextlib
import math
import signal
import sys
import threading
from collections.abc import Iterator
from typing import Any

from geoscaler.clock import WALL_CLOCK, Clock, WallClock
from geoscaler.optim.events import Controller, ProgressEvent
from geoscaler.pipeline.job import JobObserver


def command_started_at(called_at: float | None, clock: WallClock = WALL_CLOCK) -> float:
    """The instant a command's time budget counts from: ``called_at`` (when
    :func:`geoscaler.cli.main` was called from Python), else this process's start."""
    return clock.process_start() if called_at is None else called_at


class DownsampleProgress(JobObserver):
    """One tqdm bar for a downsampling job, named by phase: the views the first step needs,
    the optimisation steps (with the views still being cached alongside), the scoring of the
    report's rows on the validation views, writing the files.

    Steps show the loss, the best validation PSNR-fg and the time left: the step rate's
    estimate, or the time budget's end when that comes first.

    Args:
        enabled: False: draw nothing.
        learned: the job's method is learned (steps come before the scoring).
        clock: where the time left is read.
    """

    FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]"

    def __init__(self, enabled: bool = True, learned: bool = True, clock: Clock = WALL_CLOCK):
        from tqdm import tqdm

        self.clock = clock
        self.bar = tqdm(
            total=1,
            desc="loading",
            unit="view",
            bar_format=self.FORMAT,
            disable=not enabled,
            leave=False,
            dynamic_ncols=True,
        )
        self.deadline: float | None = None
        self.phase = "caching"
        self.learned = learned
        self.first_step: tuple[float, int] | None = None

    def write(self, text: str) -> None:
        """Print a line to stderr without breaking the bar."""
        self.bar.write(text, file=sys.stderr)

    def stage(self, what: str, done: int, total: int) -> None:
        """The job's scoring of the rows, and the writing of the files."""
        if what.startswith("scoring") and (self.phase == "done" or not self.learned):
            self._phase("scoring", "scoring on the validation views", total)
            self.bar.n = done
            self.bar.refresh()
        elif what == "writing":
            self._phase("writing", "writing the files", 1)

    def _phase(self, phase: str, description: str, total: int) -> None:
        if self.phase != phase:
            self.phase = phase
            self.bar.set_description_str(description, refresh=False)
            self.bar.set_postfix_str("", refresh=False)
            self.bar.reset(total=total)

    def method_started(self, name: str, scale: int, time_budget: float | None) -> None:
        """A learned method starts now; its budget, if any, ends ``time_budget`` s later."""
        if time_budget is not None:
            self.deadline = self.clock.now() + time_budget

    def on_event(self, event: ProgressEvent) -> None:
        """Receives the method's :class:`ProgressEvent` reports."""
        bar = self.bar
        if event.phase == "caching":
            bar.set_description_str("caching the first views", refresh=False)
            bar.total, bar.n = event.total, event.done
            bar.refresh()
            return
        if event.phase == "done":
            self.phase = "done"
            return
        if self.phase == "caching":
            self._phase("steps", "optimising", event.total_steps)
            bar.unit = "step"
            self.first_step = (self.clock.now(), event.step)
        bar.total = event.total_steps  # a layout race's losers' steps come on top
        bar.n = event.step
        postfix = []
        if math.isfinite(event.loss):
            postfix.append(f"loss {event.loss:.3g}")
        if math.isfinite(event.best_psnr):
            postfix.append(f"best PSNR-fg {event.best_psnr:.2f} dB")
        if event.done < event.total:
            postfix.append(f"views {event.done}/{event.total}")
        left = self.time_left(event)
        if left is not None:
            postfix.append(f"left {_clock(left)}")
        bar.set_postfix_str(", ".join(postfix), refresh=False)
        bar.refresh()

    def time_left(self, event: ProgressEvent) -> float | None:
        """Seconds to the step limit at the current rate, or to the budget's end if sooner."""
        estimates = []
        if self.first_step is not None and event.step > self.first_step[1]:
            began, first = self.first_step
            rate = (self.clock.now() - began) / (event.step - first)
            estimates.append(rate * max(event.total_steps - event.step, 0))
        if self.deadline is not None:
            estimates.append(max(self.deadline - self.clock.now(), 0.0))
        return min(estimates) if estimates else None

    def close(self) -> None:
        self.bar.close()


def _clock(seconds: float) -> str:
    minutes, seconds = divmod(int(round(seconds)), 60)
    return f"{minutes}:{seconds:02d}"


@contextlib.contextmanager
def stop_on_interrupt(controller: Controller, say) -> Iterator[None]:
    """While active, a first SIGINT asks ``controller`` to stop; a second one aborts.

    Only the main thread can take signals; elsewhere (e.g. a GUI worker) this does nothing and
    the caller stops the controller itself.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    presses = 0

    def handler(signum, frame):
        nonlocal presses
        presses += 1
        if presses > 1:
            raise KeyboardInterrupt
        controller.stop()
        say(
            "stopping: the best result so far will be written once the current phase ends "
            "(view caching cannot be cut short); Ctrl-C again to abort"
        )

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


class CompareProgress(JobObserver):
    """A tqdm bar over a comparison's units of work (total set on the first report)."""

    def __init__(self, bar: Any, prefix: str = ""):
        self.bar = bar
        self.prefix = prefix

    def stage(self, what: str, done: int, total: int) -> None:
        if what == "caching Q":  # views, not units of work: shown beside the bar
            self.bar.set_postfix_str(f"{self.prefix}caching Q: {done}/{total} views")
            return
        self.bar.total = total
        self.bar.n = done
        self.bar.set_postfix_str(self.prefix + what, refresh=False)
        self.bar.refresh()
