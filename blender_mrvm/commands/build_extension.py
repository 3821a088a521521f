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
import tomllib
import zipfile
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


# Python wheels the extension bundles (Blender installs the ones for its platform and Python), since what runs inside
# Blender (render-dataset, image planes, the capture import) needs packages Blender's own Python does not have:
# - openexr: the colour render is read from Blender's EXR, depth and normal maps are written as EXR;
# - pillow: every PNG (views, masks, image planes);
# - trimesh: OFF meshes (ModelNet's format; Blender has no importer);
# - assimp-py: COLLADA, ASCII FBX, 3DS and other formats Blender has no importer for.
# (scipy is optional there: without it an object's outline keeps every vertex.) The tests run Blender as a module in
# the project's venv, which has them all; tests/test_addon.py installs the zip into a Blender whose Python lacks them.
# The pins are the versions tested. The wheels are fetched from the package index at build time (never at run time)
# into a cache. Linux wheels are manylinux_2_28 (glibc 2.28, which Blender 4.2 and later need anyway).
BUNDLED_WHEELS = ("assimp-py==1.1.0", "openexr==3.5.3", "pillow==13.0.0", "trimesh==5.2.0")
WHEEL_PLATFORMS = ("win_amd64", "macosx_11_0_arm64", "manylinux_2_28_x86_64", "manylinux_2_28_aarch64")
# Blender's names of those platforms (the manifest's ``platforms``), for a zip a platform (--split-platforms).
BLENDER_PLATFORMS = ("windows-x64", "macos-arm64", "linux-x64", "linux-arm64")
# The Pythons of the Blenders the extension installs into: 4.2 to 5.0 run Python 3.11, 5.1 and later 3.13. Blender
# takes the Python versions an extension supports from its wheels' tags and refuses to install one whose wheels
# are for none of its own ("This Python version (3.13) isn't compatible with (3.11)"), so every one is bundled.
BLENDER_PYTHONS = ("3.11", "3.13")
WHEEL_CACHE = PACKAGE_DIR.parent / ".cache" / "extension_wheels"
"""Where --wheels auto keeps the downloaded wheels: the repository's .cache, wherever the command runs from."""
ALL_BLENDER_PLATFORMS = ("windows-x64", "windows-arm64", "macos-x64", "macos-arm64", "linux-x64", "linux-arm64")
"""Every platform Blender builds for (a manifest without ``platforms`` installs on each)."""


def fetch_wheels(dest: Path) -> list[Path]:
    """Download :data:`BUNDLED_WHEELS` for every platform in :data:`WHEEL_PLATFORMS` and Python in
    :data:`BLENDER_PYTHONS` into ``dest`` (a folder a Python and platform, kept: a later build reuses them) and return
    them, one file a name; MRVMError with pip's last line when the index cannot be reached."""
    dest = Path(dest)
    found: dict[str, Path] = {}
    for py in BLENDER_PYTHONS:
        for plat in WHEEL_PLATFORMS:
            folder = dest / f"py{py}-{plat}"
            folder.mkdir(parents=True, exist_ok=True)
            for req in BUNDLED_WHEELS:
                res = subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
                                      "--python-version", py, "--platform", plat, "-q", "-d", str(folder), req],
                                     capture_output=True, text=True)
                if res.returncode != 0:
                    said = (res.stderr or res.stdout).strip().splitlines() or ["pip failed"]
                    raise MRVMError(f"cannot download {req} for Python {py} on {plat}: {said[-1]}")
            for w in bundled_in(folder):  # a pure wheel (trimesh) is the same file for each: bundled once
                found.setdefault(w.name, w)
    return sorted(found.values(), key=lambda w: w.name)


def bundled_in(folder: Path) -> list[Path]:
    """The wheels of :data:`BUNDLED_WHEELS` (at their pinned versions) in ``folder``, sorted (a cache may also hold
    wheels of versions pinned before)."""
    stems = {req.split("==")[0].replace("-", "_").lower() + "-" + req.split("==")[1] + "-" for req in BUNDLED_WHEELS}
    return sorted(w for w in Path(folder).glob("*.whl") if any(w.name.lower().startswith(st) for st in stems))


def wheel_pythons(wheels: list[Path]) -> set[str]:
    """Which of :data:`BLENDER_PYTHONS` wheels' file names are for: a ``cp311`` wheel for 3.11, a stable-ABI
    (``abi3``) one for its version and later, a pure ``py3`` one for every one."""
    out: set[str] = set()
    for w in wheels:
        python_tag, abi_tag = w.name[:-4].split("-")[-3:-1]
        for tag in python_tag.split("."):
            if tag == "py3":
                out.update(BLENDER_PYTHONS)
            elif tag[:3] in ("cp3", "py3") and tag[3:].isdigit():
                minor = int(tag[3:])
                out.update(py for py in BLENDER_PYTHONS
                           if int(py.split(".")[1]) == minor or abi_tag == "abi3" and int(py.split(".")[1]) > minor)
    return out


def blender_platforms_of(wheel: Path) -> set[str]:
    """The Blender platforms a wheel installs on, from its platform tag (as Blender reads it: ``any`` is every one,
    ``universal2`` both macOS ones, a compressed tag such as ``manylinux_2_17_x86_64.manylinux2014_x86_64`` each)."""
    out: set[str] = set()
    for tag in Path(wheel).name[:-4].split("-")[-1].split("."):
        if tag == "any":
            return set(ALL_BLENDER_PLATFORMS)
        system = ("windows" if tag.startswith("win") else "macos" if tag.startswith("macosx") else
                  "linux" if "linux" in tag else None)
        machines = (["x64", "arm64"] if tag.endswith("universal2") else ["x64"] if tag.endswith(("amd64", "x86_64"))
                    else ["arm64"] if tag.endswith(("arm64", "aarch64")) else [])
        out.update(f"{system}-{m}" for m in machines if system)
    return out & set(ALL_BLENDER_PLATFORMS)


def wheel_platforms(wheels: list[Path]) -> list[str]:
    """The Blender platforms on which every bundled package has a wheel, for each Python its wheels are for: the
    manifest's ``platforms`` (elsewhere Blender would install the extension without that package). In
    :data:`ALL_BLENDER_PLATFORMS` order; every one when there are no wheels or all are pure."""
    def package(w: Path) -> str:
        return Path(w).name.split("-")[0].lower()

    covered = set(ALL_BLENDER_PLATFORMS)
    for name in {package(w) for w in wheels}:
        own = [w for w in wheels if package(w) == name]
        for py in wheel_pythons(own):  # (a Python it has no wheel for at all: run() warns)
            covered &= {plat for w in own if py in wheel_pythons([w]) for plat in blender_platforms_of(w)}
    return [p for p in ALL_BLENDER_PLATFORMS if p in covered]


def build(out_dir: Path, wheels: list[Path] | None = None) -> Path:
    """Build the extension zip into ``out_dir``; with ``wheels``, a staged copy of the package that bundles them
    (listed in its manifest's ``wheels``, its ``platforms`` those every bundled package has wheels for:
    :func:`wheel_platforms`), the source folder itself otherwise."""
    return _build(out_dir, wheels, ())[0]


def build_per_platform(out_dir: Path, wheels: list[Path]) -> list[Path]:
    """One zip a platform of :data:`BLENDER_PLATFORMS` (Blender's ``build --split-platforms``): each holds that
    platform's wheels and the pure ones, and its manifest names that platform only, so a download is about a
    quarter of the one zip's."""
    return _build(out_dir, wheels, BLENDER_PLATFORMS)


def _build(out_dir: Path, wheels: list[Path] | None, platforms: tuple[str, ...]) -> list[Path]:
    import shutil
    import tempfile

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tool = find_blender_ext()
    split = ["--split-platforms"] if platforms else []
    with tempfile.TemporaryDirectory() as tmp:
        source = PACKAGE_DIR
        if wheels or platforms:
            source = Path(tmp) / PACKAGE_DIR.name
            shutil.copytree(PACKAGE_DIR, source, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
            lines = ""
            if wheels:
                (source / "wheels").mkdir()
                for w in wheels:
                    shutil.copy2(w, source / "wheels" / Path(w).name)
                listed = ", ".join(f'"./wheels/{Path(w).name}"' for w in sorted(wheels, key=lambda w: Path(w).name))
                lines += f"wheels = [{listed}]\n"
            listed_platforms = platforms or wheel_platforms(wheels or [])
            if not listed_platforms:
                raise MRVMError("the bundled wheels have no platform in common: "
                                + "; ".join(f"{Path(w).name}: {', '.join(sorted(blender_platforms_of(w)))}"
                                            for w in wheels or []))
            if platforms or len(listed_platforms) < len(ALL_BLENDER_PLATFORMS):  # none listed: every platform
                lines += "platforms = [" + ", ".join(f'"{p}"' for p in listed_platforms) + "]\n"
            text = (source / "blender_manifest.toml").read_text()
            first_table = text.index("\n[") + 1  # top-level keys, so before the first [table]
            (source / "blender_manifest.toml").write_text(f"{text[:first_table]}{lines}\n{text[first_table:]}")
        res = subprocess.run([sys.executable, str(tool), "build", "--source-dir", str(source),
                              "--output-dir", str(out_dir), *split], capture_output=True, text=True)
    if res.returncode != 0:
        raise MRVMError(f"extension build failed: {(res.stdout + res.stderr).strip().splitlines()[-1]}")
    manifest = tomllib.loads((PACKAGE_DIR / "blender_manifest.toml").read_text())
    stem = f"{manifest['id']}-{manifest['version']}"
    zips = [out_dir / f"{stem}-{p.replace('-', '_')}.zip" for p in platforms] or [out_dir / f"{stem}.zip"]
    for z in zips:
        if not z.is_file():
            raise MRVMError(f"extension build did not produce {z}")
    return zips


def validate(path: Path) -> None:
    """Validate a package zip (or source folder) with Blender's own validator."""
    res = subprocess.run([sys.executable, str(find_blender_ext()), "validate", str(path)], capture_output=True, text=True)
    if res.returncode != 0 or "Success" not in res.stdout:
        raise MRVMError(f"extension is invalid: {(res.stdout + res.stderr).strip()}")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="dist", help="output folder for the zip (default: dist)")
    p.add_argument("--wheels", default="auto", metavar="auto|none|DIR",
                   help="bundle what the extension runs inside Blender and Blender's Python lacks (openexr, "
                        "pillow, trimesh, assimp-py) for Windows, macOS and Linux, Python 3.11 and 3.13: auto "
                        f"(default) downloads the wheels into {WHEEL_CACHE} once (and stops, building nothing, when "
                        "the package index cannot be reached); none (for a Blender whose Python has them); or a "
                        "folder of .whl files")
    p.add_argument("--split-platforms", action="store_true",
                   help="one zip a platform (Windows x64, macOS arm64, Linux x64 and arm64), each with its own "
                        "wheels only: about a quarter of the one zip's size; a Blender installs only its own")


def run(args) -> int:
    from ..guards import check_folder_writable

    check_folder_writable(Path(args.out), "extension output folder")
    wheels: list[Path] = []
    if args.wheels == "auto":
        try:
            wheels = fetch_wheels(WHEEL_CACHE)
        except MRVMError as e:  # (it built without them, with a warning and exit 0: a release job shipped a zip
            # whose Render Dataset and image planes stop with 'no module' in every installed Blender)
            raise MRVMError(f"{e}; nothing was built: build where the package index can be reached, give a folder "
                            "of wheels (--wheels DIR), or --wheels none for a Blender whose Python has openexr and "
                            "pillow") from None
    elif args.wheels != "none":
        folder = Path(args.wheels)
        # the wheel cache keeps a subfolder a Python and platform (fetch_wheels): those, else the folder's own
        found = (sorted(folder.glob("*/*.whl")) or sorted(folder.glob("*.whl"))) if folder.is_dir() else []
        wheels = list({w.name: w for w in found}.values())  # (a pure wheel sits in several subfolders)
        if not wheels:
            raise MRVMError(f"--wheels {args.wheels}: not a folder of .whl files (or auto, or none)")
    missing = [py for py in BLENDER_PYTHONS if wheels and py not in wheel_pythons(wheels)]
    if missing:
        print(f"warning: no wheel for Python {', '.join(missing)}: Blender refuses to install the extension where it "
              "runs that Python (Python 3.11: Blender 4.2 to 5.0; 3.13: 5.1 and later)", file=sys.stderr)
    if args.split_platforms:
        zips = build_per_platform(Path(args.out), wheels)
    else:
        zips = [build(Path(args.out), wheels)]
    for z in zips:
        validate(z)
        m = tomllib.loads(zipfile.ZipFile(z).read("blender_manifest.toml").decode())
        n = len(m.get("build", {}).get("generated", {}).get("wheels", m.get("wheels", [])))  # a platform's own
        plats = m.get("build", {}).get("generated", {}).get("platforms", m.get("platforms", []))
        where = f", installs on {', '.join(plats)}" if plats else ""
        print(f"built {z} ({z.stat().st_size / 1024:.0f} KiB{f', {n} wheels' if n else ''}{where})")
    print("install it with Edit > Preferences > Get Extensions > Install from Disk")
    return 0
