"""Progress and cancellation for long work.

Long-running core functions are generators that yield :class:`Progress` events after each unit of
work. Callers choose how to drive them:

- the CLI iterates to the end with a ``tqdm`` bar (:func:`run_with_tqdm`), or, when stderr is a file
  or a pipe (where tqdm prints nothing), with plain progress lines (:func:`progress_line`);
- a Blender modal operator advances the generator one step per timer tick, so the UI stays
  responsive, and cancels by calling ``gen.close()``; the generator's ``finally`` blocks then
  restore whatever it changed.

The generator's return value (``StopIteration.value``) is the result of the work.
"""

from __future__ import annotations

import contextlib
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


def as_step_of(gen: ProgressGen, done: int, total: int, label) -> ProgressGen:
    """Re-yield a sub-task's events as one step of a larger task: each at ``done`` of ``total`` with the
    message ``label(event)``; returns the sub-task's result (``yield from``)."""
    while True:
        try:
            p = next(gen)
        except StopIteration as stop:
            return stop.value
        yield Progress(done, total, label(p))


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
    with sigint_flag() as interrupted:
        events = _between_events(gen, interrupted)
        try:
            while True:
                try:
                    event = next(events)
                except StopIteration as stop:
                    return stop.value
                sys.stdout.write(progress_json(event, desc) + "\n")
                sys.stdout.flush()
        finally:
            events.close()  # closes gen too, wherever this ended (a KeyboardInterrupt while writing included)


@contextlib.contextmanager
def sigint_flag(announce: str = ""):
    """Turn Ctrl-C (SIGINT) into a flag (a list that gains the signal number) for the block's duration; the
    caller checks it between progress events and closes its generator there, at a unit boundary, where the work
    can keep what it finished (training saves a checkpoint). With ``announce``, the first Ctrl-C prints it to
    stderr and hands SIGINT back to the handler before, so a second one stops at once. Off the main thread
    (where Python cannot catch signals) nothing changes and the flag stays empty."""
    import signal
    import threading

    flag: list[int] = []
    previous = None
    if threading.current_thread() is threading.main_thread():
        def handler(signum, frame):
            flag.append(signum)
            if announce:
                signal.signal(signal.SIGINT, previous)
                sys.stderr.write(f"\n{announce}\n")
                sys.stderr.flush()

        previous = signal.signal(signal.SIGINT, handler)
    try:
        yield flag
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _between_events(gen: ProgressGen, flag: list[int]) -> ProgressGen:
    """``gen``'s events, raising KeyboardInterrupt before the next one once ``flag`` is set; ``gen`` is closed
    (at the event it last yielded, so its unit in progress finished) when this generator ends in any way."""
    try:
        while True:
            if flag:
                raise KeyboardInterrupt
            try:
                event = next(gen)
            except StopIteration as stop:
                return stop.value
            yield event
    finally:
        gen.close()


def run_with_tqdm(gen: ProgressGen, desc: str = "", unit: str = "it", disable: bool | None = None,
                  between_units: bool = False) -> Any:
    """Drive a progress generator with a tqdm bar on stderr; return its result.

    With ``MRVM_PROGRESS=json`` in the environment each event is instead one JSON line on stdout
    (:func:`progress_json`), which the add-on's worker runner parses; Ctrl-C then closes the generator between
    events. ``between_units`` does the same on a terminal or in a log: the first Ctrl-C lets the unit in
    progress finish (a training step, whose checkpoint is then saved) and says so, a second stops at once.
    """
    import os

    if os.environ.get(PROGRESS_ENV, "").lower() == "json":
        return _run_with_json(gen, desc)
    if between_units:
        note = f"{desc or 'work'}: stopping after the {unit} in progress (Ctrl-C again to stop at once)"
        with sigint_flag(note) as flag:
            return run_with_tqdm(_between_events(gen, flag), desc, unit, disable)
    if disable is None and not _is_tty(sys.stderr):
        # tqdm stays silent when stderr is a file or a pipe: print plain lines there instead
        quiet = os.environ.get("TQDM_DISABLE", "").lower() in ("1", "true", "yes")
        return _run_with_lines(gen, desc, unit, quiet)
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


def _is_tty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


LINE_INTERVAL_S = 30.0
"""Plain progress lines (output to a file or a pipe): at most one per this many seconds, plus one per 10%."""


def progress_line(event: Progress, desc: str, unit: str, elapsed: float) -> str:
    """``desc: 120/480 view (25%) message, 42 s`` (one line of a log)."""
    total = f"/{event.total}" if event.total else ""
    pct = f" ({100.0 * event.done / event.total:.0f}%)" if event.total else ""
    msg = f" {event.message}" if event.message else ""
    return f"{desc or 'progress'}: {event.done}{total} {unit}{pct}{msg}, {elapsed:.0f} s"


def _run_with_lines(gen: ProgressGen, desc: str, unit: str, quiet: bool = False) -> Any:
    """Drive ``gen`` printing :func:`progress_line` at the first event, every 10% and at least every
    LINE_INTERVAL_S seconds, and once at the end (nothing when ``quiet``)."""
    import time

    t0 = time.monotonic()
    last_t, last_decile, event = -1e9, -1, None
    try:
        while True:
            try:
                event = next(gen)
            except StopIteration as stop:
                if event is not None and not quiet:
                    sys.stderr.write(progress_line(event, desc, unit, time.monotonic() - t0) + " (done)\n")
                    sys.stderr.flush()
                return stop.value
            now = time.monotonic()
            decile = int(10 * event.done / event.total) if event.total else -1
            if not quiet and (now - last_t >= LINE_INTERVAL_S or decile > last_decile):
                sys.stderr.write(progress_line(event, desc, unit, now - t0) + "\n")
                sys.stderr.flush()
                last_t, last_decile = now, decile
    except KeyboardInterrupt:
        gen.close()
        raise


def iter_events(gen: ProgressGen) -> Iterator[Progress]:
    """Iterate over the events only (tests)."""
    yield from gen
