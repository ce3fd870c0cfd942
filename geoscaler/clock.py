"""The one clock, and the time budgets read from it.

Every reading of time in the library goes through a :class:`Clock` that the caller passes in:
commands use :class:`WallClock`; tests drive a :class:`ManualClock` and see exactly the
instants they set. A :class:`Budget` is a span of that clock (a start, a length, seconds kept
back for whoever comes after) and answers what a job under a time limit asks: how long has
gone, how long is left, whether a cost still fits, what share of the rest a phase may take.
Instants and durations are float seconds on the clock's own scale (``time.perf_counter()`` for
the wall clock).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol


class Clock(Protocol):
    """Something that tells the time: seconds on a monotonic scale of its own."""

    def now(self) -> float:
        """The current instant, in seconds."""
        ...


class WallClock:
    """The machine's monotonic clock (``time.perf_counter``)."""

    def now(self) -> float:
        return time.perf_counter()

    def process_start(self) -> float:
        """The instant this process started, on this clock, so that a command's budget covers
        the interpreter's start and the imports too (Linux, from ``/proc``, to 10 ms;
        elsewhere: now)."""
        try:
            ticks = os.sysconf("SC_CLK_TCK")
            fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
            started = int(fields[19]) / ticks  # field 22, starttime, in ticks since boot
            uptime = float(Path("/proc/uptime").read_text().split()[0])
            return self.now() - max(uptime - started, 0.0)
        except (OSError, ValueError, IndexError, AttributeError):
            return self.now()


class ManualClock:
    """A clock that moves only when told to: :meth:`advance` or :meth:`set`."""

    def __init__(self, start: float = 0.0) -> None:
        self.instant = float(start)

    def now(self) -> float:
        return self.instant

    def advance(self, seconds: float) -> None:
        """Move the clock ``seconds`` on (not back)."""
        if seconds < 0:
            raise ValueError(f"a clock does not go back ({seconds} s)")
        self.instant += seconds

    def set(self, instant: float) -> None:
        """Move the clock to ``instant`` (not before now)."""
        self.advance(instant - self.instant)


@dataclass(frozen=True)
class Budget:
    """A span of wall-clock time: from ``start`` for ``seconds`` (None: no limit), of which the
    last ``reserve`` seconds belong to whoever runs after this work (scoring, export).

    Attributes:
        clock: where the time is read.
        start: the instant the budget counts from.
        seconds: its length (None: unlimited; every cost fits).
        reserve: seconds kept back at its end.
    """

    clock: Clock
    start: float
    seconds: float | None = None
    reserve: float = 0.0

    @classmethod
    def from_now(cls, clock: Clock, seconds: float | None, reserve: float = 0.0) -> Budget:
        """A budget of ``seconds`` starting now."""
        return cls(clock, clock.now(), seconds, reserve)

    @property
    def limited(self) -> bool:
        """Whether there is a limit at all."""
        return self.seconds is not None

    @property
    def end(self) -> float:
        """The instant the work must be done by: the budget's end less the reserve (infinite
        without a limit)."""
        if self.seconds is None:
            return math.inf
        return self.start + self.seconds - self.reserve

    def now(self) -> float:
        """The clock's current instant."""
        return self.clock.now()

    def elapsed(self) -> float:
        """Seconds since the start."""
        return self.clock.now() - self.start

    def left(self) -> float:
        """Seconds until :attr:`end` (negative once past it; infinite without a limit)."""
        return self.end - self.clock.now()

    def fits(self, cost: float) -> bool:
        """Whether ``cost`` seconds of work started now end by :attr:`end`."""
        return cost <= self.left()

    def expired(self) -> bool:
        """Whether :attr:`end` has passed."""
        return self.left() <= 0.0

    def share(self, fraction: float) -> Budget:
        """A budget from now for ``fraction`` of the time left (unlimited stays unlimited)."""
        now = self.clock.now()
        if self.seconds is None:
            return Budget(self.clock, now)
        return Budget(self.clock, now, max(fraction * (self.end - now), 0.0))

    def until(self, instant: float) -> Budget:
        """A budget from now that ends at ``instant`` or at this one's end, the earlier."""
        now = self.clock.now()
        end = min(instant, self.end)
        return Budget(self.clock, now, None if math.isinf(end) else max(end - now, 0.0))

    def keeping(self, seconds: float) -> Budget:
        """This budget with ``seconds`` more kept back at its end."""
        return replace(self, reserve=self.reserve + seconds)


WALL_CLOCK = WallClock()
"""The machine's clock: what commands pass in, and what a caller that passes no clock gets."""


def unlimited(clock: Clock = WALL_CLOCK) -> Budget:
    """A budget without a limit, from now on ``clock``: every cost fits."""
    return Budget(clock, clock.now())
