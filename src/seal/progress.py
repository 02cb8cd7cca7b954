"""Progress for long commands, on a terminal and in a log file alike.

rich's `Progress` draws a live bar on a terminal and nothing at all otherwise until the job ends,
so a recording or a training started in the background (``nohup ... > log``) showed no sign of
life for hours. `Progress` here is rich's, plus one plain line per task every ``log_every``
seconds when the console is not a terminal. It writes to stderr unless given a console: stdout
is where a command prints its JSON answer.

    [progress 00:12:31] recording libero_10: 140/500 (28%)
"""

from __future__ import annotations

import time

from rich import progress as _rich
from rich.console import Console


class Progress(_rich.Progress):
    """rich's progress display that also writes periodic plain lines when not on a terminal."""

    def __init__(self, *columns, log_every: float = 60.0, **kwargs):
        kwargs.setdefault("console", Console(stderr=True))  # stdout is for a command's JSON answer
        super().__init__(*columns, **kwargs)
        self.log_every = float(log_every)
        self._t0 = time.monotonic()
        self._last_log = self._t0

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:  # an error or Ctrl-C: its one line is the last word, not a half-done bar
            self.live.transient = True
        super().__exit__(exc_type, exc, tb)

    def update(self, task_id, **kwargs) -> None:
        super().update(task_id, **kwargs)
        self._maybe_log()

    def advance(self, task_id, advance: float = 1) -> None:
        super().advance(task_id, advance)
        self._maybe_log()

    def _maybe_log(self) -> None:
        if self.console.is_terminal:
            return
        now = time.monotonic()
        if now - self._last_log >= self.log_every:
            self._last_log = now
            self._log_lines()

    def _log_lines(self) -> None:
        elapsed = time.strftime("%H:%M:%S", time.gmtime(time.monotonic() - self._t0))
        for task in self.tasks:
            if not task.visible:
                continue
            done = f"{task.completed:g}" + (f"/{task.total:g} ({100 * task.completed / task.total:.0f}%)"
                                            if task.total else "")
            info = task.fields.get("info") or ""
            self.console.print(f"[progress {elapsed}] {task.description}: {done} {info}".rstrip(),
                               markup=False, highlight=False, soft_wrap=True)


BarColumn = _rich.BarColumn
MofNCompleteColumn = _rich.MofNCompleteColumn
TextColumn = _rich.TextColumn
TimeElapsedColumn = _rich.TimeElapsedColumn
TimeRemainingColumn = _rich.TimeRemainingColumn
