"""One progress display over a whole batch: inputs done, frames per second, time left.

On a terminal a tqdm bar over the batch's frames; otherwise (a log file, a cluster job) a plain line every
`interval` seconds and one at the end. Frames count when their input finishes; the rate is over this
invocation's runs (runs finished by an earlier batch count as done but not toward the rate)."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class BatchProgress:
    def __init__(self, inputs: int, frames: int, stream: TextIO | None = None, interval: float = 5.0):
        self.inputs, self.frames = inputs, max(frames, 0)
        self.stream = stream or sys.stderr
        self.interval = interval
        self.done = self.failed = self.frames_done = self.frames_now = 0
        self.started = self._printed = time.monotonic()
        self._bar = None
        if self.stream.isatty():
            from tqdm import tqdm

            self._bar = tqdm(total=self.frames or None, desc="batch", unit="frame", file=self.stream,
                             dynamic_ncols=True)
            self._bar.set_postfix_str(self._inputs_text())

    def finished(self, record: dict, frames: int, earlier: bool = False) -> None:
        """One input finished (`earlier`: by an earlier batch); `frames`: how many it had (estimated if failed)."""
        self.done += 1
        self.failed += record["status"] == "failed"
        self.frames_done += frames
        if not earlier:
            self.frames_now += frames
        if self._bar is not None:
            self._bar.update(frames)
            self._bar.set_postfix_str(self._inputs_text())

    def note(self, text: str) -> None:
        """A line of its own (above the bar on a terminal)."""
        if self._bar is not None:
            self._bar.write(f"batch: {text}", file=self.stream)
        else:
            print(f"batch: {text}", file=self.stream, flush=True)

    def tick(self, force: bool = False) -> None:
        """The plain line, when `interval` seconds have passed since the last one (or `force`)."""
        now = time.monotonic()
        if self._bar is None and (force or now - self._printed >= self.interval):
            self._printed = now
            print(f"batch: {self.line()}", file=self.stream, flush=True)

    def line(self) -> str:
        elapsed = time.monotonic() - self.started
        rate = self.frames_now / elapsed if elapsed > 0 else 0.0
        left = self.frames - self.frames_done
        eta = f", about {_duration(left / rate)} left" if rate > 0 and left > 0 else ""
        return (f"{self._inputs_text()}, {self.frames_done}/{self.frames} frames, {rate:.1f} frames/s, "
                f"{_duration(elapsed)} elapsed{eta}")

    def _inputs_text(self) -> str:
        failed = f" ({self.failed} failed)" if self.failed else ""
        return f"{self.done}/{self.inputs} inputs{failed}"

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        else:
            self.tick(force=True)


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    hours, rest = divmod(seconds, 3600)
    minutes, seconds = divmod(rest, 60)
    if hours:
        return f"{hours} h {minutes:02d} min"
    return f"{minutes} min {seconds:02d} s" if minutes else f"{seconds} s"
