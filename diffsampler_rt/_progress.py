"""A dependency-free progress bar on stderr (the runtime pulls in nothing but numpy/ORT)."""
from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, total: int, desc: str, enabled: bool = True, width: int = 30):
        self.total, self.desc, self.enabled, self.width = total, desc, enabled, width
        self.done = 0
        self.start = time.monotonic()

    def update(self, k: int = 1) -> None:
        self.done += k
        if not self.enabled:
            return
        frac = self.done / max(1, self.total)
        bar = "#" * int(frac * self.width)
        rate = self.done / max(1e-9, time.monotonic() - self.start)
        sys.stderr.write(f"\r{self.desc} [{bar:<{self.width}}] {self.done}/{self.total} "
                         f"({rate:.1f}/s)")
        if self.done >= self.total:
            sys.stderr.write("\n")
        sys.stderr.flush()
