"""``Progress``: the one-line progress report of a run (and of the studies' long loops)."""

from __future__ import annotations

import sys
import time


class Progress:
    """A one-line progress report with elapsed time and an estimate of the time left.

    The clock starts at construction and again at ``update(0)``: a caller that compiles after
    creating the bar calls ``update(0)`` once compiled, so that neither the elapsed time nor the
    estimate (elapsed / done x left) counts the compilation (it used to: the first "left" of a
    stress case was 40x too high)."""

    def __init__(self, total: int, label: str, stream=sys.stderr):
        self.total, self.label, self.stream = total, label, stream
        self.t0 = time.perf_counter()
        self.tty = stream.isatty()
        self.last_pct = -1

    def update(self, done: int, extra: str = ""):
        if done == 0:
            self.t0 = time.perf_counter()
        el = time.perf_counter() - self.t0
        eta = el / done * (self.total - done) if done else float("nan")
        pct = int(100 * done / self.total)
        bar = "#" * (pct // 5) + "." * (20 - pct // 5)
        line = f"{self.label} [{bar}] {pct:3d}% {done}/{self.total} {extra} elapsed {el:6.1f} s, left ~{eta:6.1f} s"
        if self.tty:
            self.stream.write("\r" + line + ("\n" if done == self.total else ""))
            self.stream.flush()
        elif pct // 10 != self.last_pct // 10 or done == self.total:
            self.stream.write(line + "\n")
            self.stream.flush()
        self.last_pct = pct
