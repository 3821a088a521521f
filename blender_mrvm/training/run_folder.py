"""What a run folder holds and where training continues from (bpy-free).

The rule: nothing that exists is overwritten or deleted without ``force``, and a run folder's state
is found from its checkpoints themselves, newest complete one first (``checkpoints/latest`` is only a
hint: it may be empty, torn or name a deleted step; a checkpoint may be truncated by a full disk or a
copy). The trainer calls :func:`resume_point` once before its first step.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from ..datasets.format import atomic_write_text, remove_entries
from ..errors import InputError
from ..models.checkpoint_files import STATE_FILE, checkpoint_folders, checkpoint_problem, step_of

RUN_FILES = ("checkpoints", "metrics.jsonl", "config.json", "run_record.jsonl")
"""What training writes into a run folder (plus ``summary_rank*.json``); ``run_record.jsonl``: one line a start
(``training/provenance.py``)."""


def holds_run(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds (part of) a training run: a checkpoint, even a damaged one, or metrics."""
    run_dir = Path(run_dir)
    if checkpoint_folders(run_dir / "checkpoints"):
        return True
    m = run_dir / "metrics.jsonl"
    return m.is_file() and m.stat().st_size > 0


def _warn(msg: str) -> None:
    print(f"warning: {msg}", file=sys.stderr)


def load_state(ck: Path) -> dict[str, Any]:
    """The trainer state of a checkpoint folder; InputError naming the file when it does not load."""
    import torch

    try:
        state = torch.load(Path(ck) / STATE_FILE, map_location="cpu", weights_only=True)
    except Exception as e:  # UnpicklingError, EOFError, RuntimeError (zip), ...
        first = (str(e).strip().splitlines() or [type(e).__name__])[0][:200]
        raise InputError(f"{Path(ck) / STATE_FILE} does not load ({type(e).__name__}: {first})") from None
    if not isinstance(state, dict) or "step" not in state or "optimizer" not in state:
        raise InputError(f"{Path(ck) / STATE_FILE} is not a trainer state")
    return state


def newest_complete(run_dir: Path) -> tuple[Path | None, dict[str, Any] | None, list[str]]:
    """(checkpoint, its trainer state, what was wrong with newer ones) of the newest checkpoint whose
    files are whole and whose state loads; (None, None, problems) when there is none."""
    problems: list[str] = []
    for ck in checkpoint_folders(Path(run_dir) / "checkpoints"):
        why = checkpoint_problem(ck)
        if not why:
            try:
                return ck, load_state(ck), problems
            except InputError as e:
                why = str(e)
        problems.append(f"{ck.name}: {why}")
    return None, None, problems


def clear_run(run_dir: Path) -> None:
    """Remove what training wrote into ``run_dir`` (only that): --no-resume --force."""
    run_dir = Path(run_dir)
    remove_entries(run_dir, [*RUN_FILES, *(p.name for p in run_dir.glob("summary_rank*.json"))])


def resume_point(run_dir: Path, resume: bool = True, force: bool = False,
                 main: bool = True) -> tuple[Path | None, dict[str, Any] | None]:
    """Where training starts: (checkpoint, trainer state) to resume from, or (None, None) for a fresh run.

    - ``resume`` and a complete checkpoint: the newest complete one (damaged newer ones are named in a
      warning and left on disk);
    - ``resume`` and checkpoints that are all damaged: InputError (a restart would overwrite them),
      unless ``force``, which starts over;
    - not ``resume`` in a folder that holds a run: InputError unless ``force``;
    - starting over with ``force`` removes the old run's checkpoints, metrics and config (rank 0 only).
    """
    run_dir = Path(run_dir)
    if not holds_run(run_dir):
        return None, None
    if resume:
        ck, state, problems = newest_complete(run_dir)
        if ck is not None:
            if problems and main:
                _warn(f"skipped damaged checkpoint(s) {'; '.join(problems)}; resuming from {ck.name}")
            if main:
                trim_metrics(run_dir / "metrics.jsonl", int(state["step"]))
            return ck, state
        if not problems:  # metrics but no checkpoint: a run killed before its first checkpoint
            if main:
                trim_metrics(run_dir / "metrics.jsonl", 0)
            return None, None
        if not force:
            raise InputError(f"run folder {run_dir} has no complete checkpoint to resume from "
                             f"({'; '.join(problems)[:300]}); pass --no-resume --force to start the run over")
    elif not force:
        steps = [step_of(c) for c in checkpoint_folders(run_dir / "checkpoints")]
        what = f"checkpoints up to step {max(steps)}" if steps else "metrics.jsonl"
        raise InputError(f"run folder {run_dir} holds a run ({what}); resume it (without --no-resume) "
                         "or pass --force to remove it and start over")
    if main:
        clear_run(run_dir)
    return None, None


def check_not_past(run_dir: Path, found: Path, step: int, iterations: int, flag: str, how: str = "") -> None:
    """A resume of the run at ``step`` (checkpoint ``found``) with fewer ``iterations`` is refused before anything
    is written: config.json would record steps never trained while the model is further on (``train`` and
    ``sem2nerf train``; ``flag`` names the setting, ``how`` where the user sets it)."""
    if step > iterations:
        raise InputError(f"the run in {run_dir} is at step {step} ({Path(found).name}), past {flag} ({iterations}): "
                         f"raise it{how} to {step} or more to continue the run, or start it over (--no-resume --force)")


def trim_metrics(path: Path, step: int) -> int:
    """Drop the lines of ``metrics.jsonl`` past ``step`` (written after the checkpoint a run resumes from,
    so a resumed run does not repeat them) and any torn line (a full disk); returns how many went."""
    path = Path(path)
    if not path.is_file():
        return 0
    keep, dropped = [], 0
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        try:
            rec = json.loads(line)
            ok = isinstance(rec, dict) and int(rec.get("step", 0)) <= step
        except (ValueError, TypeError):
            ok = False
        if ok:
            keep.append(line)
        else:
            dropped += 1
    if dropped:
        atomic_write_text(path, "".join(ln + "\n" for ln in keep))
    return dropped


def check_device(name: str) -> None:
    """InputError when a CUDA device is asked for and torch sees none (before any work starts)."""
    n = (name or "cpu").strip().lower()
    if not n.startswith("cuda"):
        return
    import torch

    if not torch.cuda.is_available():
        raise InputError(f"device {name} was asked for, but torch sees no CUDA GPU here (use device cpu)")
    idx = int(n[5:]) if n.startswith("cuda:") else 0
    if idx >= torch.cuda.device_count():
        raise InputError(f"device {name}: torch sees only {torch.cuda.device_count()} CUDA GPU(s)")


def check_loss(loss: float, step: int, last_checkpoint: Path | None, what: str = "loss") -> None:
    """Stop training at the first step whose loss is not finite (NaN weights, NaN poses, a diverging
    learning rate): going on would only write NaN checkpoints over good ones."""
    import math

    if math.isfinite(loss):
        return
    from ..errors import TrainingStopped

    raise TrainingStopped(f"training stopped at step {step}: the {what} is {loss} (NaN or infinite weights, poses or "
                          f"images, or a learning rate that diverges); {_kept(last_checkpoint)}")


def _kept(last_checkpoint: Path | None) -> str:
    return (f"the last checkpoint ({Path(last_checkpoint).name}) is kept" if last_checkpoint
            else "no checkpoint was written")


def check_weights(model, step: int, last_checkpoint: Path | None, extra: dict | None = None) -> None:
    """Stop training after step ``step`` when its update left NaN, infinite or diverged weights (larger than
    ``checkpoint.DIVERGED_WEIGHT``: a learning rate that diverges) in ``model`` or the ``extra`` tensors saved
    with it: they are never saved, so the last checkpoint stays the last good one (:func:`check_loss` sees only
    the loss of the weights before the update)."""
    from .checkpoint import DIVERGED_WEIGHT, nonfinite_weights

    tensors = {**model.state_dict(), **(extra or {})}
    bad = nonfinite_weights(tensors, DIVERGED_WEIGHT)
    if not bad:
        return
    from ..errors import TrainingStopped

    peak = float(tensors[bad[0]].detach().abs().max())
    more = f", and {len(bad) - 1} more tensors" if len(bad) > 1 else ""
    raise TrainingStopped(f"training stopped at step {step}: its update left NaN, infinite or diverged weights "
                          f"({bad[0]} reaches {peak:.3g}{more}; a learning rate that diverges?), which were not saved; "
                          f"{_kept(last_checkpoint)}")
