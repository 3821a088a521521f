"""Output guards: nothing that exists is overwritten or deleted without ``--force`` (bpy-free).

Every command that writes somewhere a user named calls one of these before any work starts, so a
refusal costs nothing and leaves everything as it was. The panel's operators write into fresh
temporary folders or ask the user first.
"""

from __future__ import annotations

from pathlib import Path

from .errors import OutputError


def _shown(names: list[str]) -> str:
    return ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")


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
        present = sorted(p.name for p in path.iterdir() if p.name not in ours)
        if present:
            raise OutputError(f"{what} {path} already holds files ({_shown(present)}); choose another folder "
                              f"or pass {flag} to write over them")
    return path


def check_not_input(out: Path, inputs: dict[str, Path | None]) -> None:
    """An output folder must not be one of the inputs (writing there would replace them: a reference
    object's ground truth by predictions), whatever ``--force`` says."""
    o = Path(out).expanduser().resolve()
    for what, p in inputs.items():
        if p is not None and Path(p).expanduser().resolve() == o:
            raise OutputError(f"the output folder {out} is the {what} folder; choose another folder")
