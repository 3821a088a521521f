"""Progress and cancellation for long work.

Long-running core functions are generators that yield :class:`Progress` events after each unit of
work. Callers choose how to drive them:

- the CLI iterates to the end with a ``tqdm`` bar (:func:`run_with_tqdm`);
- a Blender modal operator advances the generator one step per timer tick, so the UI stays
  responsive, and cancels by calling ``gen.close()``; the generator's ``finally`` blocks then
  restore whatever it changed.

The generator's return value (``StopIteration.value``) is the result of the work.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any, Generator, Iterator


@dataclass(frozen=True)
class Progress:
    """One step of long work."""

    done: int
    """Units finished so far (views, iterations, images)."""
    total: int
    """Units in all; 0 when unknown."""
    message: str = ""
    """What is being worked on, for a status line."""
    skipped: int = 0
    """Units found already finished (resume) and not redone."""

    @property
    def fraction(self) -> float:
        return self.done / self.total if self.total else 0.0


ProgressGen = Generator[Progress, None, Any]


def run_to_end(gen: ProgressGen) -> Any:
    """Drive a progress generator without reporting; return its result."""
    while True:
        try:
            next(gen)
        except StopIteration as stop:
            return stop.value


PROGRESS_ENV = "MRVM_PROGRESS"
"""Set to ``json`` (as the add-on's worker runner does) to get machine-readable progress on stdout."""


def progress_json(event: Progress, desc: str = "") -> str:
    """One stdout line for a parent process: ``{"mrvm": "progress", "done": .., "total": .., ...}``."""
    import json

    return json.dumps({"mrvm": "progress", "done": event.done, "total": event.total, "message": event.message,
                       "skipped": event.skipped, "desc": desc})


def _run_with_json(gen: ProgressGen, desc: str) -> Any:
    """Cancel is cooperative here: SIGINT (the worker runner's cancel) only sets a flag, checked
    between progress events, so the generator is closed at a unit boundary. A KeyboardInterrupt
    raised at a random bytecode could land inside a Python callback that Blender runs during a
    render and be swallowed there (the child then ran to the end), or abort a unit half-written."""
    import signal
    import threading

    interrupted: list[int] = []
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, lambda signum, frame: interrupted.append(signum))
    try:
        while True:
            if interrupted:
                raise KeyboardInterrupt
            try:
                event = next(gen)
            except StopIteration as stop:
                return stop.value
            sys.stdout.write(progress_json(event, desc) + "\n")
            sys.stdout.flush()
    except KeyboardInterrupt:
        gen.close()
        raise
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def run_with_tqdm(gen: ProgressGen, desc: str = "", unit: str = "it", disable: bool | None = None) -> Any:
    """Drive a progress generator with a tqdm bar on stderr; return its result.

    With ``MRVM_PROGRESS=json`` in the environment each event is instead one JSON line on stdout
    (:func:`progress_json`), which the add-on's worker runner parses.
    """
    import os

    if os.environ.get(PROGRESS_ENV, "").lower() == "json":
        return _run_with_json(gen, desc)
    from tqdm import tqdm

    bar = None
    try:
        while True:
            try:
                event = next(gen)
            except StopIteration as stop:
                return stop.value
            if bar is None:
                bar = tqdm(total=event.total or None, desc=desc, unit=unit, file=sys.stderr,
                           disable=disable, dynamic_ncols=True)
            bar.n = event.done
            if event.message:
                bar.set_postfix_str(event.message, refresh=False)
            bar.refresh()
    except KeyboardInterrupt:
        gen.close()
        raise
    finally:
        if bar is not None:
            bar.close()


def iter_events(gen: ProgressGen) -> Iterator[Progress]:
    """Iterate over the events only (tests)."""
    yield from gen
