"""A rich progress bar as a ``callback(done, total)``, shown only when stderr is a terminal."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeRemainingColumn


@contextmanager
def progress_bar(description: str, enabled: bool | None = None) -> Iterator[Callable[[int, int], None]]:
    show = sys.stderr.isatty() if enabled is None else enabled
    columns = (TextColumn("{task.description}"), BarColumn(), TaskProgressColumn(), TimeRemainingColumn())
    with Progress(*columns, console=Console(stderr=True), transient=True, disable=not show) as bar:
        task = bar.add_task(description, total=None)

        def update(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        yield update


@contextmanager
def steps_bar(description: str, total: int, enabled: bool | None = None) -> Iterator[Callable[[str], None]]:
    """A rich progress bar over ``total`` named steps (on stderr, only when it is a terminal):
    ``step(label)`` says which one starts now."""
    show = sys.stderr.isatty() if enabled is None else enabled
    columns = (TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
               TextColumn("{task.fields[label]}"))
    with Progress(*columns, console=Console(stderr=True), transient=True, disable=not show) as bar:
        task = bar.add_task(description, total=total, label="")
        started = [0]

        def step(label: str) -> None:
            bar.update(task, completed=started[0], label=label)
            started[0] += 1

        yield step
