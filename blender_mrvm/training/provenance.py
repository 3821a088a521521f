"""What a run records so that a researcher can repeat it: the code (package version, the git commit of the
source tree and whether it was modified), the libraries, the thread count, the command line, and a digest of
the data it read. bpy-free; nothing here changes a result.

Where it goes: ``train`` and ``sem2nerf train`` add one line per start (a new run or a resume) to
``<run>/run_record.jsonl`` and the same record to every checkpoint's metadata (``provenance``, beside
``train_config``: a checkpoint copied alone still says how it was made); ``eval`` and ``sem2nerf eval`` write
it into ``eval.json`` (``provenance``).

Why the thread count: torch's CPU reductions split their work by thread, so the same run with 1 and 2 threads
differs in the last bits of its first losses and drifts from there (measured: 1e-7 relative at step 1, every
weight different after 8 steps); ``threads = 0`` means every core but one, which is another number on another
machine. Rendering (``eval``, ``synthesize``) runs each ray chunk on one core and does not depend on it.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import os
import platform
import subprocess
import sys
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterable

RUN_RECORD = "run_record.jsonl"
"""The run folder's record of every start (one JSON line each)."""

PACKAGE_ROOT = Path(__file__).resolve().parents[1]


@lru_cache(maxsize=1)
def source_state() -> dict[str, Any]:
    """{"commit": the git commit of the checkout the package runs from (None outside one, or without git),
    "modified": whether its tracked files under the package differ from that commit (None when unknown)}."""
    out: dict[str, Any] = {"commit": None, "modified": None}
    repo = PACKAGE_ROOT.parent
    if not (repo / ".git").exists():
        return out
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}  # read-only: git status must not touch the index

    def git(*args: str) -> subprocess.CompletedProcess | None:
        try:
            return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, timeout=10, env=env)
        except (OSError, subprocess.SubprocessError):
            return None

    head = git("rev-parse", "HEAD")
    if head is None or head.returncode != 0:
        return out
    out["commit"] = head.stdout.strip()
    st = git("status", "--porcelain", "--untracked-files=no", "--", str(PACKAGE_ROOT))
    if st is not None and st.returncode == 0:
        out["modified"] = bool(st.stdout.strip())
    return out


def environment(threads: int | None = None, device: str | None = None, when: bool = True) -> dict[str, Any]:
    """The code, libraries, machine and command of this process: what :data:`RUN_RECORD`, checkpoints and
    eval reports record. ``threads``: the torch thread count the work ran with (default: torch's now); ``when``:
    with the time (not in reports whose reruns should compare equal, as ``eval.json``)."""
    import numpy as np
    import torch

    from .. import __version__

    return {"blender_mrvm": __version__, **source_state(),
            "python": platform.python_version(), "torch": torch.__version__, "numpy": np.__version__,
            "threads": int(torch.get_num_threads() if threads is None else threads),
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
            "device": device, "platform": platform.platform(), "machine": platform.machine(),
            "argv": [str(a) for a in sys.argv],
            **({"time_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")} if when else {})}


def scenes_digest(scenes: Iterable[Any]) -> dict[str, Any]:
    """{"objects", "views", "sha256"} of loaded objects (``datasets.loaders.ObjectScene`` or Sem2NeRF's masked
    objects): the digest covers, object by object in order, the category and name, the view ids, the decoded
    images, the poses and intrinsics and, where loaded, the masks: the same data give the same digest whatever
    folder, machine or image encoder they came through."""
    import numpy as np

    h = hashlib.sha256()
    n_obj = n_views = 0
    for s in scenes:
        n_obj += 1
        images = np.ascontiguousarray(s.images)
        n_views += int(images.shape[0])
        h.update(f"{getattr(s, 'category', '')}/{getattr(s, 'name', '')}\n".encode())
        h.update(repr([int(v) for v in (getattr(s, "view_ids", None) or [])]).encode())
        h.update(str(images.dtype).encode() + repr(images.shape).encode())
        h.update(images.tobytes())
        h.update(np.ascontiguousarray(np.asarray(s.c2w, np.float64)).tobytes())
        for k in getattr(s, "intrinsics", None) or []:
            h.update(repr(tuple(float(getattr(k, f)) for f in ("fx", "fy", "cx", "cy"))
                          + (int(k.width), int(k.height))).encode())
        masks = getattr(s, "masks", None)
        if masks is not None:
            h.update(np.ascontiguousarray(masks).tobytes())
    return {"objects": n_obj, "views": n_views, "sha256": h.hexdigest()}


def file_sha256(path: Path) -> str | None:
    """sha256 of a file (a model file: which weights an evaluation scored), None when it cannot be read."""
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    except OSError:
        return None
    return h.hexdigest()


def init_record(name: str | None) -> dict[str, Any] | None:
    """{"name", "file", "sha256"} of the checkpoint a fine-tune starts from (``init_checkpoint``; 'shipped' names
    a file that changes with the package), None without one or when it cannot be found."""
    if not name:
        return None
    from ..errors import InputError
    from .config import resolve_init_checkpoint

    try:
        f = resolve_init_checkpoint(str(name))
    except (InputError, OSError):
        return {"name": str(name), "file": None, "sha256": None}
    return {"name": str(name), "file": str(Path(f).resolve()), "sha256": file_sha256(f)}


def append_record(run_dir: Path, record: dict[str, Any]) -> None:
    """One line of :data:`RUN_RECORD` in ``run_dir`` (appended: a resume adds its own start)."""
    import json

    with open(Path(run_dir) / RUN_RECORD, "a", encoding="utf-8") as f:
        f.write(json.dumps(record, default=str) + "\n")
