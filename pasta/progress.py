"""Rich progress bars for the long stages and the one-line summary each stage ends with.

Every bar shows what is done out of how many, a status text (the latest metrics), the elapsed time and
an estimate of the time left. Training shows its epochs (``pasta.train.progress.EpochBars``), evaluation
its configurations (:class:`ScoreBar`) and data generation its demonstrations (``flows/data.py``).
"""

from __future__ import annotations

from typing import TypeVar

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

__all__ = ["ScoreBar", "stage_progress", "summary"]

Result = TypeVar("Result")


LOG_WIDTH = 200  # columns of a bar written to a file or pipe, where rich would otherwise cut it at 80


def stage_progress(console: Console | None = None) -> Progress:
    """A rich ``Progress`` whose bars read ``description  ━━━  done/total  status  elapsed  ETA left``.

    Add bars with a ``status`` field (``progress.add_task(description, total=n, status="")``).
    """
    return Progress(TextColumn("{task.description}"), BarColumn(bar_width=20), MofNCompleteColumn(),
                    TextColumn("{task.fields[status]}"), TimeElapsedColumn(), TextColumn("ETA"),
                    TimeRemainingColumn(), console=console or default_console())


def default_console() -> Console:
    """Standard output: the terminal's width, or :data:`LOG_WIDTH` when it is not a terminal."""
    console = Console()
    return console if console.is_terminal else Console(width=LOG_WIDTH)


def summary(stage: str, text: str, wall_s: float, console: Console | None = None) -> str:
    """Print and return a stage's one-line summary: ``<stage> done in <wall>: <text>``."""
    line = f"{stage} done in {wall_s:.0f} s: {text}"
    (console or default_console()).print(line, highlight=False, soft_wrap=True)
    return line


class ScoreBar:
    """A bar over an evaluation's (seed, configuration) pairs with the mean performance so far.

    Use as a context manager; :meth:`done` records one result (anything with a ``performance``) and
    returns it, so a list comprehension can pass its results through.
    """

    def __init__(self, description: str, total: int, console: Console | None = None) -> None:
        self.progress = stage_progress(console)
        self.bar: TaskID = self.progress.add_task(description, total=total, status="")
        self.scores: list[float] = []

    def __enter__(self) -> ScoreBar:
        self.progress.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.progress.stop()

    @property
    def mean(self) -> float:
        """The mean performance of the results so far (NaN before the first)."""
        return sum(self.scores) / len(self.scores) if self.scores else float("nan")

    def done(self, result: Result) -> Result:
        """Count ``result`` (its ``performance``) and show the new mean."""
        self.scores.append(float(result.performance))
        self.progress.update(self.bar, advance=1, status=f"mean performance {self.mean:.3f}")
        return result
