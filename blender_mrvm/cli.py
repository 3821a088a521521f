"""The headless command-line interface: python -m blender_mrvm <command> ...

Each command lives in ``commands/<name>.py`` with ``add_arguments(parser)`` and ``run(args) -> int``;
those modules import nothing heavy at module level, so ``--help`` is instant and a command that
needs torch does not make another one need it. User errors (:class:`MRVMError`) print one line,
``error: ...``, and exit non-zero.

Inside Blender the same CLI runs as::

    blender --background --python-expr "import bl_ext.user_default.blender_mrvm.cli as c; c.main_blender()" -- render-dataset ...
    blender --background -P scripts/mrvm_blender.py -- render-dataset ...
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from pathlib import Path

from .errors import InputError, MRVMError, OutputError
from .threads import apply_omp_defaults

apply_omp_defaults()  # before any command imports torch (see threads.py)

# command name -> (module in commands/, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "render-dataset": ("render_dataset", "render a ShapeNet-style multi-view dataset from objects or mesh files"),
    "build-extension": ("build_extension", "build the installable Blender extension zip"),
    "bench": ("bench", "run a benchmark and write its figures to CSV/PNG"),
    "contact-sheet": ("contact_sheet", "write a PNG contact sheet of a rendered dataset"),
    "recover-poses": ("recover_poses", "recover camera poses of photos (pycolmap) into a capture folder"),
    "preview-library": ("preview_library", "render a contact sheet PNG of the procedural object library"),
    "make-shapenet": ("make_shapenet", "render a ShapeNet-13-style set from the procedural library with the papers' splits"),
    "make-captures": ("make_captures", "render capture-like scenes: library objects in textured rooms along hand-held camera paths"),
    "demo": ("demo", "the main job on the shipped defaults (what `make demo` runs)"),
    "fetch-weights": ("fetch_weights", "set-up: convert the offline LPIPS/VGG16 weights into the local cache"),
    "train": ("train", "train or fine-tune a novel-view model of any kind: NeRFormer+MRVM, GPNR (torchrun for several processes)"),
    "eval": ("eval", "evaluate a checkpoint (SRN protocol): PSNR, SSIM, LPIPS per category -> JSON + PNG grid"),
    "sem2nerf": ("sem2nerf", "Sem2NeRF: part mask + camera -> radiance field with semantic maps (train, render, eval, bench)"),
    "synthesize": ("synthesize", "synthesize novel views of posed references with a checkpoint (PNG/EXR, optional .blend)"),
}


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions keep their lines (the commands' examples, one a line, were reflowed into one paragraph), and an
    option whose help does not speak of its default gets it appended."""

    def _get_help_string(self, action):
        text = action.help or ""
        d = action.default
        if ("default" in text.lower() or not action.option_strings or d is None or d is False or d == []
                or d is argparse.SUPPRESS):
            return text
        return text + " (default: %(default)s)"


class Parser(argparse.ArgumentParser):
    """argparse with the CLI's one-line errors: ``error: <what>`` (and where the help is), exit 2, and the CLI's
    help layout (:class:`HelpFormatter`)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"error: {message} (see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="python -m blender_mrvm", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (module, help_text) in COMMANDS.items():
        mod = importlib.import_module(f".commands.{module}", __package__)
        p = sub.add_parser(name, help=help_text, description=(mod.__doc__ or help_text).strip())
        mod.add_arguments(p)
        p.set_defaults(_module=mod)
    return parser


def _break_as_interrupt():
    """Windows: the panel's Esc reaches a worker as Ctrl-Break (SIGBREAK: ``worker._signal``), which by default ends
    the process at once; take it as Ctrl-C (whatever handles SIGINT now: ``progress.sigint_flag``'s flag, else
    KeyboardInterrupt), so the step in progress is finished and kept. Returns what to restore (None: nothing done)."""
    import signal
    import threading

    sigbreak = getattr(signal, "SIGBREAK", None)
    if sigbreak is None or threading.current_thread() is not threading.main_thread():
        return None

    def handler(signum, frame):
        h = signal.getsignal(signal.SIGINT)
        if callable(h):
            h(signal.SIGINT, frame)
        elif h != signal.SIG_IGN:
            raise KeyboardInterrupt

    try:
        return sigbreak, signal.signal(sigbreak, handler)
    except (OSError, ValueError):
        return None


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    rank, world = _torchrun_rank()
    restore = _break_as_interrupt()
    try:
        return _main(args, rank, world)
    finally:
        if restore is not None:
            import signal

            signal.signal(*restore)


def _main(args, rank: int, world: int) -> int:
    try:
        try:
            return int(args._module.run(args) or 0)
        except (ImportError, RuntimeError) as e:
            if interrupted_import(e):  # Ctrl-C while a library loaded: an interrupt, not a broken install
                raise KeyboardInterrupt from e
            raise
    except MRVMError as e:
        if rank == 0 or not isinstance(e, (InputError, OutputError)):  # (every rank finds the same bad input)
            print(f"error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        if rank == 0:
            kept = interrupted_keeps(args, world)
            print(f"error: interrupted{'; ' + kept if kept else ''}", file=sys.stderr)
        return 130
    except OSError as e:
        msg = os_error_message(e)
        if msg is None:
            raise
        print(f"error: {msg}", file=sys.stderr)
        return 2
    except (RuntimeError, MemoryError) as e:
        msg = memory_error_message(e, args.command)
        if msg is None:
            raise
        print(f"error: {msg}", file=sys.stderr)
        return 2


RESUMED = "the views finished so far are kept; the same command goes on from them"
NOTHING_WRITTEN = "nothing was written"
TRAIN_KEPT = ("the run's checkpoints are kept (the first Ctrl-C saves the step in progress); the same command goes on "
              "from the newest")


def _out_as_it_was(args) -> str:
    return f"nothing was written ({args.out} is as it was)" if getattr(args, "out", None) else NOTHING_WRITTEN


def _bench_kept(args) -> str:
    """A bench that writes its rows as it measures (model, tradeoff, train, capture, render) keeps them; its files in
    --out are this run's (earlier results are refused, or removed by --force when the measuring starts)."""
    out = getattr(args, "out", None)
    results = getattr(getattr(args, "_bench", None), "RESULTS", ()) if args.command == "bench" else ()
    if args.command == "sem2nerf":
        from .models.sem2nerf.inputs import BENCH_RESULTS as results
    there = [n for n in results if out is not None and (Path(out) / n).is_file()]
    return f"the figures measured so far are in {Path(out) / there[0]}" if there else NOTHING_WRITTEN


def _recover_poses_kept(args) -> str:
    again = "the same command without --force" if getattr(args, "force", False) else "the same command"
    return f"the stages finished so far are kept in {Path(args.out) / 'colmap'}; {again} goes on from them"


def _sem2nerf_kept(args) -> str:
    action = getattr(args, "sem2nerf_command", None)
    if action == "train":
        return TRAIN_KEPT
    if action == "bench":
        return _bench_kept(args)
    return _out_as_it_was(args)  # render and eval write when they finish


INTERRUPTED = {
    "render-dataset": RESUMED,
    "make-shapenet": RESUMED,
    "make-captures": RESUMED,
    "demo": RESUMED,  # (its dataset; the scene, the sheet and metrics.json are written when it finishes)
    "synthesize": _out_as_it_was,
    "eval": _out_as_it_was,
    "contact-sheet": NOTHING_WRITTEN,
    "preview-library": NOTHING_WRITTEN,
    "recover-poses": _recover_poses_kept,
    "train": TRAIN_KEPT,
    "sem2nerf": _sem2nerf_kept,
    "bench": _bench_kept,
}
"""What the Ctrl-C line says a command kept (a string, or one made from its arguments). It had said "finished work is
kept" for every command, also for those that write only when they finish (eval, synthesize: nothing was kept) and
without saying that the same command resumes. A command not named gets the bare line."""


def interrupted_keeps(args, world: int = 1) -> str:
    """The clause after ``error: interrupted; `` for ``args``' command ('' for none)."""
    if world > 1:
        return "the checkpoints saved so far are kept (under torchrun the steps since the last one are not)"
    kept = INTERRUPTED.get(args.command, "")
    try:
        return kept(args) if callable(kept) else kept
    except Exception:  # noqa: BLE001  (the line after an interrupt must not become a traceback)
        return ""


def _torchrun_rank() -> tuple[int, int]:
    """(rank, world size) of this process under torchrun (its RANK / WORLD_SIZE), (0, 1) otherwise: a message every
    rank would print alike (a bad argument, Ctrl-C) is printed by rank 0 only, not once a process."""
    try:
        return int(os.environ.get("RANK", "0")), int(os.environ.get("WORLD_SIZE", "1"))
    except ValueError:
        return 0, 1


def interrupted_import(e: BaseException) -> bool:
    """Whether ``e`` is a library's import failing because Ctrl-C came while it loaded: pycolmap re-raises the
    KeyboardInterrupt its C++ module's initialisation got as 'RuntimeError: Cannot import the C++ backend ... Make
    sure that you successfully install the package', a traceback that blamed the install."""
    seen, cause = set(), e
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            return True
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return False


MEMORY_HINTS = {
    "train": ("train holds every image of its objects in memory: render the dataset smaller (render-dataset "
              "--resolution), or lower train.objects_per_step / train.rays_per_object (--config)"),
    "sem2nerf": "lower --objects-per-step (train), or render with --quality preview (render)",
}
"""What lowers the memory of a command whose options differ from the generic hint's (train has no --chunk)."""


def memory_error_message(e: BaseException, command: str | None = None) -> str | None:
    """One line for running out of memory (torch's CPU allocator, CUDA, numpy's MemoryError): the sizes a user
    can lower, not a traceback; None for other errors (bugs keep their traceback). Files are written atomically,
    so what was finished before is whole."""
    text = str(e)
    cuda = type(e).__name__ == "OutOfMemoryError" or "CUDA out of memory" in text
    if not (cuda or isinstance(e, MemoryError) or "can't allocate memory" in text
            or "not enough memory" in text or "failed to allocate" in text.lower()):
        return None
    where = "the GPU" if cuda else "this machine"
    first = text.strip().splitlines()[0][:160] if text.strip() else type(e).__name__
    hint = MEMORY_HINTS.get(command or "", "lower --chunk (rays per forward pass), the image or reference size, or "
                                            "the batch")
    return f"out of memory on {where} ({first}): {hint}; what was finished before is kept"


DISK_ERRNOS = ("ENOSPC", "EDQUOT", "EROFS", "EFBIG")
"""Errors of the place a command writes to, not bugs: reported in one line (files are written
atomically, so what was finished before is whole)."""


def os_error_message(e: OSError) -> str | None:
    """One line for an OSError the user can fix (a full disk, a quota, a read-only file system, a
    permission), None for others (bugs keep their traceback)."""
    import errno

    codes = {getattr(errno, n) for n in DISK_ERRNOS if hasattr(errno, n)} | {errno.EACCES, errno.EPERM}
    if e.errno == errno.ENAMETOOLONG:  # a name longer than the file system allows (255 bytes)
        name = str(e.filename or "")
        return f"{e.strerror or e}{f' ({name[:80]}...)' if name else ''}: choose a shorter name"
    if e.errno not in codes:
        return None
    where = f" ({e.filename})" if e.filename else ""
    return f"{e.strerror or e}{where}; what was finished before is kept"


def main_blender() -> int:
    """Entry point for ``blender --background ... -- <command> ...``: arguments after ``--``."""
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    code = main(argv)
    if code:
        sys.exit(code)
    return code
