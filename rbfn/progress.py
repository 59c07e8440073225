"""Where a long loop stands, for whoever reports it: the loop writes, a reporter reads.

A loop that can take minutes (the colony, the refinement, the closed-loop tuning) takes an
optional `Progress` and tells it what it does and how far it got (`at`); it does no I/O
itself. `rbfn.studies.cli.announced` reads it every HEARTBEAT_S seconds from its own thread
and logs `line()`, which says what is done, what remains and about how long that takes. The
reader sees plain attribute writes, at worst one step old.
"""

from __future__ import annotations

import time

__all__ = ["Progress"]


class Progress:
    """A loop's position: `done` of `total` `unit` in `what`, started at `started` (perf_counter s)."""

    def __init__(self) -> None:
        self.what, self.unit = "", ""
        self.done = self.total = self._first = 0
        self.started = time.perf_counter()

    def at(self, what: str, done: int, total: int, unit: str = "steps") -> None:
        """`done` of `total` `unit` of `what` are done; a new `what` (or total) starts a new stage,
        whose rate the time left is estimated from (a resumed colony's first report included)."""
        if what != self.what or total != self.total:
            self.what, self.unit, self.total, self._first = what, unit, int(total), int(done)
            self.started = time.perf_counter()
        self.done = int(done)

    def line(self) -> str | None:
        """'WHAT: DONE / TOTAL UNIT, about T s left' (the time from this stage's rate so far); 'WHAT'
        alone for a stage of no counted steps (total 0); None before any stage started."""
        if not self.what:
            return None
        if not self.total:
            return self.what
        text = f"{self.what}: {self.done} / {self.total} {self.unit}"
        ran = self.done - self._first
        if 0 < ran and self.done < self.total:
            left = (time.perf_counter() - self.started) / ran * (self.total - self.done)
            text += f", about {left:.0f} s left"
        return text
