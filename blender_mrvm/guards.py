"""Output guards: nothing that exists is overwritten or deleted without ``--force`` (bpy-free).

Every command that writes somewhere a user named calls one of these before any work starts, so a
refusal costs nothing and leaves everything as it was. The panel's operators write into fresh
temporary folders or ask the user first.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from .errors import OutputError

LOCK_FILE = ".lock"
"""The lock file of a folder a command writes into (:func:`output_lock`); the folder checks ignore it."""

PARTIAL_PREFIX = ".mrvm-partial-"
"""Temporary files and folders a command builds inside a folder it holds locked (short: a long but legal
name must not overflow the 255 bytes of a file name); a run killed leaves them, the next run's
:func:`sweep_partials` removes them."""


def _shown(names: list[str]) -> str:
    return ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")


def _ours_always(name: str) -> bool:
    """A lock file, or what a killed run left (swept by the next run that holds the folder)."""
    return name == LOCK_FILE or name.startswith(PARTIAL_PREFIX)


def check_new_file(path: Path, force: bool = False, what: str = "file", flag: str = "--force") -> Path:
    """``path`` may be written: it does not exist, or ``force`` allows replacing it; never a folder."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{what} {path} is a folder; name a file")
    if path.exists() and not force:
        raise OutputError(f"{what} {path} already exists; pass {flag} to replace it")
    parent = path.parent if str(path.parent) else Path(".")
    if parent.exists() and not parent.is_dir():
        raise OutputError(f"cannot write {path}: {parent} is not a folder")
    return path


def check_output_folder(path: Path, force: bool = False, what: str = "output folder",
                        flag: str = "--force", ours: tuple[str, ...] = ()) -> Path:
    """``path`` may be written into: it does not exist, is empty, holds only ``ours`` (names this command
    writes and may update), or ``force`` allows writing over what is there."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{what} {path} exists and is not a folder")
    if path.is_dir() and not force:
        present = sorted(p.name for p in path.iterdir() if p.name not in ours and not _ours_always(p.name))
        if present:
            raise OutputError(f"{what} {path} already holds files ({_shown(present)}); choose another folder "
                              f"or pass {flag} to write over them")
    return path


def check_folder_writable(path: Path, what: str = "output folder") -> Path:
    """``path`` can become a folder this process writes into: it is no file, and the nearest part of it that
    exists is a folder this process may write into. (What it holds is :func:`check_output_folder`'s business.)"""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{what} {path} exists and is not a folder")
    probe = path
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"cannot write {what} {path}: {probe} is not a folder")
    if not os.access(probe, os.W_OK):
        raise OutputError(f"cannot write into {probe}")
    return path


def same_path(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name one file or folder: as the file system sees it when both exist (macOS's and
    Windows' ignore case, so ``Data`` is ``data``, which resolved paths compared as strings missed on macOS; a hard
    link, a Windows 8.3 short name or mapped drive too), else as resolved paths."""
    a, b = Path(a).expanduser(), Path(b).expanduser()
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return a.resolve() == b.resolve()


def check_not_input(out: Path, inputs: dict[str, Path | None]) -> None:
    """An output folder must not be one of the inputs (writing there would replace them: a reference
    object's ground truth by predictions), whatever ``--force`` says."""
    for what, p in inputs.items():
        if p is not None and same_path(p, out):
            raise OutputError(f"the output folder {out} is the {what} folder; choose another folder")


# ---------------------------------------------------------------------------------------------
# One process at a time in a folder
# ---------------------------------------------------------------------------------------------

def _lock_holder(fd: int) -> str:
    try:
        if hasattr(os, "pread"):
            raw = os.pread(fd, 32, 0)
        else:  # Windows
            os.lseek(fd, 0, os.SEEK_SET)
            raw = os.read(fd, 32)
        pid = raw.decode("ascii", "replace").strip()
    except OSError:
        pid = ""
    return f" (pid {pid})" if pid.isdigit() else ""


def _refuse_held(fd: int, what: str, folder: Path):
    """Close ``fd`` (a lock file another process holds) and refuse, naming that process; the caller keeps no ``fd``
    (its cleanup would remove the other process's lock file)."""
    holder = _lock_holder(fd)
    os.close(fd)
    raise OutputError(f"{what} {folder} is in use by another process{holder}; wait for it or choose another folder")


_WINDOWS_LOCK_AT = 1 << 20
"""The byte of the lock file that ``msvcrt.locking`` locks on Windows (past the pid, which others read)."""


@contextlib.contextmanager
def output_lock(folder: Path, what: str = "output folder"):
    """Hold ``folder`` (created when missing) for this process: a second command writing into it at the same
    time is refused with OutputError instead of mixing its files with this one's. A ``flock`` on
    ``<folder>/.lock`` (released by the system when the process dies, even by SIGKILL). On leaving, the lock file
    goes, and so does the folder with the parents this call created when they are empty (a refusal or a failure
    leaves nothing behind). Windows has no ``fcntl``: there a ``msvcrt.locking`` of one byte far past the pid
    (Windows' locks are mandatory: the pid stays readable), which the system also releases when the process dies;
    the lock file is closed before it is removed (Windows removes no file a handle has open)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{what} {folder} exists and is not a folder")
    made, p = [], folder
    while not p.exists() and p.parent != p:
        made.append(p)
        p = p.parent
    folder.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # Windows
        fcntl = None
    msvcrt = None
    if fcntl is None:
        try:
            import msvcrt
        except ImportError:
            msvcrt = None
    fd = None
    try:
        if fcntl is None and msvcrt is not None:
            fd = os.open(folder / LOCK_FILE, os.O_RDWR | os.O_CREAT | getattr(os, "O_BINARY", 0), 0o644)
            try:
                os.lseek(fd, _WINDOWS_LOCK_AT, os.SEEK_SET)
                msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
            except OSError:
                held, fd = fd, None  # (none of ours to remove on the way out)
                _refuse_held(held, what, folder)
            os.ftruncate(fd, 0)
            os.lseek(fd, 0, os.SEEK_SET)
            os.write(fd, f"{os.getpid()}\n".encode())
        elif fcntl is not None:
            path = folder / LOCK_FILE
            while True:
                fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    held, fd = fd, None  # (none of ours to remove on the way out)
                    _refuse_held(held, what, folder)
                try:  # the file may have been removed by its last holder between our open and lock: lock anew
                    same = os.path.samestat(os.fstat(fd), os.stat(path))
                except FileNotFoundError:
                    same = False
                if same:
                    break
                os.close(fd)
                fd = None
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield folder
    finally:
        if fd is not None and fcntl is None:  # Windows: unlock and close, then remove (it fails, harmlessly, when
            with contextlib.suppress(OSError):  # another process has opened it meanwhile)
                os.lseek(fd, _WINDOWS_LOCK_AT, os.SEEK_SET)
                msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
            os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(folder / LOCK_FILE)
        elif fd is not None:
            with contextlib.suppress(OSError):
                os.unlink(folder / LOCK_FILE)  # while still held: no one can lock the removed file meanwhile
            os.close(fd)
        for m in made:  # innermost first; only empty ones
            try:
                m.rmdir()
            except OSError:
                break


def sweep_partials(folder: Path, pattern: str = PARTIAL_PREFIX + "*") -> None:
    """Remove what a killed run left in ``folder`` (names matching ``pattern``: :data:`PARTIAL_PREFIX` ones, or a
    run folder's half-saved ``checkpoints/.step_*``); only under :func:`output_lock`, when no other run can be
    writing them."""
    import shutil

    for p in Path(folder).glob(pattern):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                p.unlink()


def check_name_length(path: Path, what: str = "output", extra: int = 0) -> None:
    """OutputError when a name in ``path`` is longer than the file system allows (``extra`` characters more for
    names the command derives from it), before any work."""
    path = Path(path)
    try:
        limit = os.pathconf(next((p for p in path.parents if p.is_dir()), Path(".")), "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):  # (a parent's name too long itself; no pathconf on Windows)
        limit = 255
    for part in path.parts:
        if len(os.fsencode(part)) + extra > limit:
            raise OutputError(f"{what} {path}: the name {part[:40]}... is {len(os.fsencode(part))} bytes long; "
                              f"the file system allows {limit - extra}")


# ---------------------------------------------------------------------------------------------
# Folders a command owns (demo_out): it may update its own files, never a user's
# ---------------------------------------------------------------------------------------------

def _sha256(path: Path) -> str:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class OwnedFolder:
    """An output folder a command owns and may rerun into (``demo --out``).

    A manifest (``marker``) records the sha256 of every file the command wrote. A rerun may replace
    those files while they are as it left them; a file the user changed since (a scene.blend edited and
    saved), a file the manifest does not know, or a folder without the manifest that holds anything is
    refused without ``force``. ``subfolders`` are the command's own working folders."""

    def __init__(self, root: Path, marker: str, files: tuple[str, ...], subfolders: tuple[str, ...] = ()):
        self.root, self.marker, self.files, self.subfolders = Path(root), marker, files, subfolders

    def _manifest(self) -> dict:
        import json

        p = self.root / self.marker
        try:
            d = json.loads(p.read_text()) if p.is_file() else {}
        except (ValueError, OSError):
            d = {}
        return d if isinstance(d, dict) and isinstance(d.get("files", {}), dict) else {}

    def check(self, force: bool = False) -> None:
        """OutputError (before any work) unless the folder is new, empty, or holds only this command's
        unchanged files; ``force`` allows writing over anything there."""
        root = self.root
        if root.exists() and not root.is_dir():
            raise OutputError(f"output {root} exists and is not a folder")
        if force or not root.is_dir():
            return
        present = sorted(p.name for p in root.iterdir() if p.name != LOCK_FILE)
        if not present:
            return
        man = self._manifest()
        if not man:
            raise OutputError(f"output folder {root} already holds files ({_shown(present)}) that this command did "
                              "not write; choose another --out or pass --force to write over them")
        known = set(self.files) | set(self.subfolders) | {self.marker}
        foreign = [n for n in present if n not in known]
        if foreign:
            raise OutputError(f"output folder {root} holds files this command did not write ({_shown(foreign)}); "
                              "move them or pass --force")
        recorded = man.get("files", {})
        changed = [n for n in self.files if (root / n).is_file() and recorded.get(n) != _sha256(root / n)]
        if changed:
            raise OutputError(f"{root / changed[0]} was changed since this command wrote it; move it away or pass "
                              "--force to replace it")

    def claim(self) -> None:
        """Create the folder and its manifest (before the first file is written)."""
        self.root.mkdir(parents=True, exist_ok=True)
        if not (self.root / self.marker).is_file():
            self._write({})

    def wrote(self, name: str) -> None:
        """Record a file the command just wrote."""
        files = dict(self._manifest().get("files", {}))
        files[name] = _sha256(self.root / name)
        self._write(files)

    def _write(self, files: dict) -> None:
        from .datasets.format import atomic_write_json

        atomic_write_json(self.root / self.marker, {"format": "blender_mrvm.owned_folder", "files": files})
