"""CPU threading that degrades gracefully on a busy machine. bpy-free, imports nothing heavy.

torch's CPU build runs its parallel regions on OpenMP (libgomp), whose idle threads spin-wait by
default. When another process holds a core (Blender itself, a second job, a render), a spinning
thread takes the core its sibling needs and every parallel region waits on a descheduled thread:
measured on the project's 2-core box with a competing process, NeRFormer ``balanced`` at 128 px took
30.1 s per view with 2 threads against 4.5 s with 1 (``docs/bench_threads.csv``). With
``OMP_WAIT_POLICY=PASSIVE`` idle threads sleep instead, and 2 threads stop being a cliff
(``python -m blender_mrvm bench threads`` measures both policies side by side).

libgomp reads the variable once, when torch is first imported, so it must be in the environment
before that: :func:`apply_omp_defaults` is called by the CLI entry point (``__main__``) and by
:func:`worker.worker_env` for the processes the add-on starts. A value the user set is kept.

The allocator is the other hidden cost (:func:`apply_malloc_defaults`): a chunk of rays makes tensors of a
few MiB, which glibc serves with ``mmap`` and gives back to the kernel when they are freed, so every
chunk page-faults its working set in again. Measured on the shipped `balanced` model, 128 px view,
2 references: 106k-134k minor page faults and 0.85-0.88 CPU s per view with glibc's defaults, 1-400 and
0.62 s with the thresholds below.
"""

from __future__ import annotations

import os
from typing import MutableMapping

OMP_DEFAULTS = {"OMP_WAIT_POLICY": "PASSIVE"}
"""What we set unless the environment already says otherwise."""
KEEP_ENV = "BLENDER_MRVM_KEEP_OMP"
"""Set to 1 to leave OpenMP's own defaults (what ``bench threads`` compares against)."""


def apply_omp_defaults(env: MutableMapping[str, str] | None = None) -> MutableMapping[str, str]:
    """Add :data:`OMP_DEFAULTS` to ``env`` (default ``os.environ``) where absent; returns it."""
    env = os.environ if env is None else env
    if env.get(KEEP_ENV) != "1":
        for k, v in OMP_DEFAULTS.items():
            env.setdefault(k, v)
    return env


MALLOC_DEFAULTS = {"M_MMAP_THRESHOLD": 32 << 20, "M_TRIM_THRESHOLD": 256 << 20}
"""glibc ``mallopt`` settings of :func:`apply_malloc_defaults`: blocks up to 32 MiB (every tensor of a
512-ray chunk) come from the heap instead of fresh ``mmap`` pages, and up to 256 MiB of freed heap stays
mapped for the next chunk instead of being trimmed (resident memory stays near the peak of a chunk)."""
KEEP_MALLOC_ENV = "BLENDER_MRVM_KEEP_MALLOC"
"""Set to 1 to leave glibc's own malloc thresholds (what ``bench threads --malloc`` compares against)."""
_MALLOPT_PARAM = {"M_TRIM_THRESHOLD": -1, "M_MMAP_THRESHOLD": -3}  # <malloc.h>
_USER_MALLOC_ENV = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_")

malloc_policy = "glibc defaults"
"""What :func:`apply_malloc_defaults` did in this process (benches record it beside their timings)."""


def apply_malloc_defaults(env: MutableMapping[str, str] | None = None) -> str:
    """Set :data:`MALLOC_DEFAULTS` with glibc's ``mallopt`` for this process; returns (and stores in
    :data:`malloc_policy`) what was done: "tuned", "glibc defaults" (:data:`KEEP_MALLOC_ENV` is 1),
    "user's MALLOC_* environment" (glibc already read the user's own thresholds) or "not glibc".

    Called by the CLI entry point (``python -m blender_mrvm``, which the add-on's worker runs too), never
    inside Blender's own process. Takes effect for blocks allocated afterwards; bit-identical results."""
    global malloc_policy
    import ctypes
    import platform

    env = os.environ if env is None else env
    if env.get(KEEP_MALLOC_ENV) == "1":
        policy = "glibc defaults"
    elif any(k in env for k in _USER_MALLOC_ENV):
        policy = "user's MALLOC_* environment"
    elif platform.libc_ver()[0] != "glibc":
        policy = "not glibc"
    else:
        try:
            libc = ctypes.CDLL(None)
            ok = all(libc.mallopt(_MALLOPT_PARAM[k], int(v)) == 1 for k, v in MALLOC_DEFAULTS.items())
        except (OSError, AttributeError):
            ok = False
        policy = "tuned" if ok else "glibc defaults"
    malloc_policy = policy
    return policy


def usable_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def auto_threads(cpus: int | None = None) -> int:
    """The torch thread count for ``threads = 0``: every usable core but one (Blender, the writer thread
    or the user's other work keep it), at least 1. On the 2-core box that is 1 thread, which measured
    best both idle (1.83 s per shipped `balanced` 128 px view against 2.25 s for 2 passive threads) and
    beside a busy process (11.4 s, where 2 spinning threads took 71.7 s)."""
    return max(1, int(usable_cores() if cpus is None else cpus) - 1)


def set_torch_threads(requested: int = 0) -> int:
    """``torch.set_num_threads(requested)``, or :func:`auto_threads` when ``requested`` is 0; returns the
    count. The one place every command picks its thread count."""
    import torch

    n = int(requested) if requested and requested > 0 else auto_threads()
    torch.set_num_threads(n)
    return n


def render_workers(requested: int = 0) -> int:
    """Rendering views (synthesis, eval, the demo, the benches): ``n`` ray chunks rendered side by side on
    threads, each chunk's ops on one core, so torch's own thread count is set to 1; returns ``n``:
    ``requested``, or every usable core when 0 (``RayModel.image_chunks``' ``workers``).

    The models' ops are small (a chunk is 512 rays), so OpenMP's per-op fork/join costs more than it gives:
    on the 2-core box, idle, the chunks of a shipped `balanced` 128 px view took 0.78-0.88 s with 2 chunk
    workers against 1.40-1.60 s with 1 thread and 1.56-1.74 s with 2 OpenMP threads (passive); the whole
    view (``bench tradeoff``) 1.01-1.06 s against 1.75 s. Chunk workers share no
    barrier, so a busy core slows them down and nothing more (the spin-wait cliff of 2
    OpenMP threads beside a busy process does not apply: ``bench threads``, `fast`, 128 px, beside a spinning
    process, 2 chunk workers 1.78 s against 2.47 s for 1 and 5.45 s for 2 spinning OpenMP threads). Training
    keeps :func:`set_torch_threads`."""
    import torch

    n = int(requested) if requested and requested > 0 else usable_cores()
    torch.set_num_threads(1)
    return max(1, n)
