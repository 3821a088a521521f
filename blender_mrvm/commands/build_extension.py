"""Build the installable extension zip with Blender's own builder (``blender --command extension build``).

The builder ships with Blender (and with the ``bpy`` module) as ``bl_pkg/cli/blender_ext.py``; it
validates ``blender_manifest.toml`` and honours its ``[build]`` exclusions. Install the zip in Blender
with Edit > Preferences > Get Extensions > Install from Disk.
"""

from __future__ import annotations

import argparse
import glob
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

from ..errors import MRVMError

PACKAGE_DIR = Path(__file__).resolve().parents[1]


def find_blender_ext() -> Path:
    """Path of Blender's extension command-line tool (bl_pkg/cli/blender_ext.py)."""
    candidates = []
    spec = importlib.util.find_spec("bpy")
    if spec and spec.origin:
        root = Path(spec.origin).parent
        candidates += glob.glob(str(root / "*" / "scripts" / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"))
    try:  # inside Blender
        import bpy

        candidates.append(os.path.join(bpy.utils.system_resource("SCRIPTS"), "addons_core", "bl_pkg", "cli", "blender_ext.py"))
    except Exception:
        pass
    for c in candidates:
        if os.path.isfile(c):
            return Path(c)
    raise MRVMError("Blender's extension builder (bl_pkg/cli/blender_ext.py) was not found; "
                    "install the bpy module or run `blender --command extension build` in blender_mrvm/")


def build(out_dir: Path) -> Path:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tool = find_blender_ext()
    res = subprocess.run([sys.executable, str(tool), "build", "--source-dir", str(PACKAGE_DIR),
                          "--output-dir", str(out_dir)], capture_output=True, text=True)
    if res.returncode != 0:
        raise MRVMError(f"extension build failed: {(res.stdout + res.stderr).strip().splitlines()[-1]}")
    import tomllib

    manifest = tomllib.loads((PACKAGE_DIR / "blender_manifest.toml").read_text())
    zip_path = out_dir / f"{manifest['id']}-{manifest['version']}.zip"
    if not zip_path.is_file():
        raise MRVMError(f"extension build did not produce {zip_path}")
    return zip_path


def validate(path: Path) -> None:
    """Validate a package zip (or source folder) with Blender's own validator."""
    res = subprocess.run([sys.executable, str(find_blender_ext()), "validate", str(path)], capture_output=True, text=True)
    if res.returncode != 0 or "Success" not in res.stdout:
        raise MRVMError(f"extension is invalid: {(res.stdout + res.stderr).strip()}")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="dist", help="output folder for the zip (default: dist)")


def run(args) -> int:
    from ..guards import check_folder_writable

    check_folder_writable(Path(args.out), "extension output folder")
    zip_path = build(Path(args.out))
    validate(zip_path)
    print(f"built {zip_path} ({zip_path.stat().st_size / 1024:.0f} KiB); install it with "
          "Edit > Preferences > Get Extensions > Install from Disk")
    return 0
