"""Clocks for tests that look at how a job spends its time."""


class TickingClock:
    """A clock that moves one second at every look, from 1 at the first."""

    def __init__(self) -> None:
        self.instant = 0.0

    def now(self) -> float:
        self.instant += 1.0
        return self.instant
