"""A progress bar on one terminal line, shared by the command-line front ends."""

from __future__ import annotations

import time
import typing


class ProgressBar:
    """``[#####-----] done/total UNIT rate/s`` on one terminal line, redrawn at most 10 times a
    second (``done UNIT`` alone when the total is not known, ``total`` <= 0)."""

    def __init__(self, stream: typing.TextIO, unit: str = 'messages', width: int = 30) -> None:
        self._stream = stream
        self._unit = unit
        self._width = width
        self._last = 0.0
        self._start = time.perf_counter()
        self._shown = False

    def __call__(self, done: int, total: int) -> None:
        now = time.perf_counter()
        if now - self._last < 0.1 and done != total:
            return
        self._last = now
        rate = done / (now - self._start) if now > self._start else 0.0
        if total > 0:
            filled = self._width * min(done, total) // total
            bar = f'[{"#" * filled}{"-" * (self._width - filled)}] {done}/{total}'
        else:
            bar = f'{done}'
        self._stream.write(f'\r{bar} {self._unit} {rate:6.1f}/s')
        self._stream.flush()
        self._shown = True

    def clear(self) -> None:
        """End the bar's line so that what follows (a message, the summary) starts on its own."""
        if self._shown:
            self._stream.write('\n')
            self._stream.flush()
            self._shown = False

    def close(self) -> None:
        self.clear()
