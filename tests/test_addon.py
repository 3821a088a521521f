"""The add-on: registration cycles, the extension zip, and the operator from a script."""

from __future__ import annotations

import json
import subprocess
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _mrvm_types(bpy):
    return sorted(n for n in dir(bpy.types) if n.startswith("MRVM_"))


def test_register_unregister_register(addon):
    import bpy

    import blender_mrvm

    registered = _mrvm_types(bpy)
    assert {"MRVM_OT_render_dataset", "MRVM_PT_main", "MRVM_PT_dataset"} <= set(registered)
    assert hasattr(bpy.types.Scene, "mrvm_dataset")
    blender_mrvm.unregister()
    assert _mrvm_types(bpy) == [] and not hasattr(bpy.types.Scene, "mrvm_dataset")
    blender_mrvm.register()
    assert _mrvm_types(bpy) == registered and hasattr(bpy.types.Scene, "mrvm_dataset")
    blender_mrvm.register()  # registering twice re-registers cleanly
    assert _mrvm_types(bpy) == registered
    assert bpy.context.preferences.addons["blender_mrvm"].preferences.device == "AUTO"


def test_every_class_in_the_package_is_registered(addon):
    import importlib
    import pkgutil

    import bpy

    import blender_mrvm

    registrable = (bpy.types.Operator, bpy.types.Panel, bpy.types.PropertyGroup, bpy.types.AddonPreferences)
    mods = [importlib.import_module("blender_mrvm.props"), importlib.import_module("blender_mrvm.prefs")]
    for sub in ("operators", "panels"):
        pkg = importlib.import_module(f"blender_mrvm.{sub}")
        for m in pkgutil.iter_modules(pkg.__path__):
            if m.name.startswith("_"):  # shared helpers, not registered themselves
                continue
            assert m.name in pkg.MODULES, f"{sub}/{m.name}.py is not in {sub}.MODULES"
            mods.append(importlib.import_module(f"blender_mrvm.{sub}.{m.name}"))
    classes = [c for mod in mods for c in vars(mod).values()
               if isinstance(c, type) and issubclass(c, registrable) and c.__module__ == mod.__name__]
    assert len(classes) >= 5
    missing = [c.__name__ for c in classes if not c.is_registered]
    assert not missing, missing
    blender_mrvm.unregister()
    try:
        still = [c.__name__ for c in classes if c.is_registered]
        assert not still, still
    finally:
        blender_mrvm.register()


def test_paths_relative_to_an_unsaved_blend_are_refused_in_every_section(empty_scene):
    """'//' in a .blend not saved yet: Blender reads it from the folder it was started in, so the Dataset's mesh
    path, Capture's photos and Novel Views' checkpoint named another file without a word (a dataset rendered from
    whatever chair.obj was there)."""
    import bpy

    from blender_mrvm.errors import InputError
    from blender_mrvm.operators import capture, dataset, synthesize

    assert not bpy.data.filepath
    scene = empty_scene
    scene.mrvm_dataset.source, scene.mrvm_dataset.source_path = "PATH", "//chair.obj"
    scene.mrvm_dataset.output_dir = "/tmp/mrvm_never_written"
    with pytest.raises(InputError, match="save the .blend first .* the mesh file or folder"):
        dataset.config_from_props(bpy.context)
    scene.mrvm_capture.images_dir, scene.mrvm_capture.output_dir = "//photos", "/tmp/mrvm_never_written"
    with pytest.raises(InputError, match="save the .blend first .* the photos"):
        capture.config_from_props(bpy.context)
    scene.mrvm_novel_views.checkpoint = "//mrvm_runs/run"
    with pytest.raises(InputError, match="save the .blend first .* the checkpoint"):
        synthesize._checkpoint(bpy.context, scene.mrvm_novel_views)


def test_bpy_free_layers_import_without_blender():
    import subprocess
    import sys

    code = ("import sys; sys.modules['bpy'] = None; sys.modules['mathutils'] = None\n"
            "import blender_mrvm, blender_mrvm.geometry.cameras, blender_mrvm.geometry.rigs, "
            "blender_mrvm.datasets.format, blender_mrvm.cli\n"
            "blender_mrvm.cli.build_parser()\n")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr


def test_extension_zip(tmp_path):
    from blender_mrvm.commands.build_extension import build, validate

    zip_path = build(tmp_path)
    validate(zip_path)
    names = zipfile.ZipFile(zip_path).namelist()
    assert "blender_manifest.toml" in names and "__init__.py" in names
    for must in ("operators/dataset.py", "panels/main.py", "scene/render.py", "geometry/cameras.py", "cli.py"):
        assert must in names
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc") or n.startswith("tests/")]
    manifest = tomllib.loads(zipfile.ZipFile(zip_path).read("blender_manifest.toml").decode())
    assert manifest["id"] == "blender_mrvm" and manifest["type"] == "add-on"
    assert manifest["blender_version_min"] == "4.2.0" and manifest["schema_version"] == "1.0.0"
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"] and "files" in manifest["permissions"]
    assert manifest["version"] == tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def _fake_wheel(folder: Path, python_tag: str = "py3", platform: str = "any", name: str = "tinypkg",
                version: str = "1.0") -> Path:
    """A minimal wheel: ``cp311`` + a platform for a binary one (abi tag = python tag), ``py3`` + ``any`` for a pure
    one (abi ``none``)."""
    abi = "none" if python_tag == "py3" else python_tag
    tag = f"{python_tag}-{abi}-{platform}"
    w = folder / f"{name}-{version}-{tag}.whl"
    with zipfile.ZipFile(w, "w") as z:
        z.writestr(f"{name}/__init__.py", "")
        z.writestr(f"{name}-{version}.dist-info/METADATA", f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
        z.writestr(f"{name}-{version}.dist-info/WHEEL", f"Wheel-Version: 1.0\nRoot-Is-Purelib: {str(abi == 'none').lower()}"
                                                        f"\nTag: {tag}\n")
        z.writestr(f"{name}-{version}.dist-info/RECORD", "")
    return w


def test_extension_zip_bundles_wheels(tmp_path):
    """With wheels (build-extension --wheels DIR, or the downloaded assimp-py ones), the zip holds them under wheels/
    and its manifest lists them, so Blender installs them; the package folder itself is left as it was."""
    from blender_mrvm.commands.build_extension import PACKAGE_DIR, build, validate

    (tmp_path / "whl").mkdir()
    wheel = _fake_wheel(tmp_path / "whl")
    before = (PACKAGE_DIR / "blender_manifest.toml").read_text()
    zip_path = build(tmp_path / "out", [wheel])
    validate(zip_path)
    z = zipfile.ZipFile(zip_path)
    assert "wheels/tinypkg-1.0-py3-none-any.whl" in z.namelist()
    manifest = tomllib.loads(z.read("blender_manifest.toml").decode())
    assert manifest["wheels"] == ["./wheels/tinypkg-1.0-py3-none-any.whl"]
    assert (PACKAGE_DIR / "blender_manifest.toml").read_text() == before and not (PACKAGE_DIR / "wheels").exists()




def test_bundled_wheels_let_every_supported_blender_install_the_extension(tmp_path, monkeypatch):
    """Blender reads the Pythons an extension supports from its wheels' tags and refuses one whose wheels are for
    none of its own. With wheels for Python 3.11 only (the zip before session 47), Blender 5.1 and later (Python
    3.13) refused it; the build now fetches every Python of BLENDER_PYTHONS, and Blender's own check (bl_pkg) passes
    for 4.2, 5.0 and 5.1. A --wheels folder without one of them is built with a warning naming it."""
    import os
    import sys
    import types

    import bpy

    from blender_mrvm.commands import build_extension as B

    sys.path.insert(0, os.path.join(bpy.utils.system_resource("SCRIPTS"), "addons_core"))
    try:
        from bl_pkg.bl_extension_utils import pkg_manifest_params_compatible_or_error, python_versions_from_wheels
    finally:
        sys.path.pop(0)

    asked = []

    def fake_pip(cmd, **kw):  # what fetch_wheels asks the index for, without the index
        py, plat, req = cmd[cmd.index("--python-version") + 1], cmd[cmd.index("--platform") + 1], cmd[-1]
        asked.append((req, py, plat))
        name, version = req.split("==")
        _fake_wheel(Path(cmd[cmd.index("-d") + 1]), "cp3" + py.split(".")[1], plat, name.replace("-", "_"), version)
        return types.SimpleNamespace(returncode=0, stdout="", stderr="")

    cache = tmp_path / "cache"
    (cache / "py3.11-win_amd64").mkdir(parents=True)
    _fake_wheel(cache / "py3.11-win_amd64", "cp311", "win_amd64", "assimp_py", "0.9")  # pinned before: not bundled
    _fake_wheel(cache, "cp311", "manylinux2014_x86_64", "assimp_py", "1.0")  # the cache's old layout: not bundled
    monkeypatch.setattr(B.subprocess, "run", fake_pip)
    wheels = B.fetch_wheels(cache)
    monkeypatch.undo()
    assert sorted(asked) == sorted((req, py, plat) for req in B.BUNDLED_WHEELS for py in B.BLENDER_PYTHONS
                                   for plat in B.WHEEL_PLATFORMS)
    assert len(wheels) == len(asked) and not [w for w in wheels if "-0.9-" in w.name or "2014" in w.name]
    assert B.wheel_pythons(wheels) == set(B.BLENDER_PYTHONS) == {"3.11", "3.13"}

    def refusals(zip_path):
        m = tomllib.loads(zipfile.ZipFile(zip_path).read("blender_manifest.toml").decode())
        pythons = [".".join(map(str, v)) for v in python_versions_from_wheels(m["wheels"])]
        return {blender: pkg_manifest_params_compatible_or_error(
                    blender_version_min=m["blender_version_min"], blender_version_max="", platforms="",
                    python_versions=pythons, this_platform="linux-x64", this_python_version=python,
                    this_blender_version=blender, error_fn=print)
                for blender, python in (((4, 2, 0), (3, 11, 9)), ((5, 0, 1), (3, 11, 13)), ((5, 1, 0), (3, 13, 2)))}

    assert refusals(B.build(tmp_path / "all", wheels)) == {(4, 2, 0): None, (5, 0, 1): None, (5, 1, 0): None}
    only_311 = [w for w in wheels if "-cp311-" in w.name]
    said = refusals(B.build(tmp_path / "old", only_311))
    assert said[(4, 2, 0)] is None and "3.13" in str(said[(5, 1, 0)])  # the check is real: 3.11 only is refused

    folder = tmp_path / "mine"
    folder.mkdir()
    for w in only_311:
        (folder / w.name).write_bytes(w.read_bytes())
    res = subprocess.run([sys.executable, "-m", "blender_mrvm", "build-extension", "--out", str(tmp_path / "d"),
                          "--wheels", str(folder)], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "warning: no wheel for Python 3.13" in res.stderr


def test_a_zip_a_platform_holds_that_platforms_wheels(tmp_path):
    """build-extension --split-platforms: a zip each for Windows, macOS arm64 and Linux x64 / arm64, each with its own
    platform's wheels and the pure ones, its manifest naming that platform and those wheels (what Blender reads)."""
    from blender_mrvm.commands import build_extension as B

    whl = tmp_path / "whl"
    whl.mkdir()
    wheels = [_fake_wheel(whl, py, plat, "binpkg") for py in ("cp311", "cp313")
              for plat in ("win_amd64", "manylinux_2_28_x86_64")]
    pure = _fake_wheel(whl, name="purepkg")
    zips = B.build_per_platform(tmp_path / "out", [*wheels, pure])
    assert [z.name for z in zips] == [f"blender_mrvm-0.1.0-{p.replace('-', '_')}.zip" for p in B.BLENDER_PLATFORMS]
    want = {"windows-x64": "win_amd64", "linux-x64": "manylinux_2_28_x86_64", "macos-arm64": None, "linux-arm64": None}
    for z, platform in zip(zips, B.BLENDER_PLATFORMS):
        B.validate(z)
        archive = zipfile.ZipFile(z)
        inside = sorted(n.split("/")[-1] for n in archive.namelist() if n.endswith(".whl"))
        own = sorted(w.name for w in wheels if want[platform] and w.name.endswith(f"-{want[platform]}.whl"))
        assert inside == sorted([*own, pure.name]), (platform, inside)
        generated = tomllib.loads(archive.read("blender_manifest.toml").decode())["build"]["generated"]
        assert generated["platforms"] == [platform]
        assert sorted(w.split("/")[-1] for w in generated["wheels"]) == inside


_INSTALL_AND_RENDER = """
import json, sys
from pathlib import Path
import bpy
zip_path, out = sys.argv[-2], Path(sys.argv[-1])
assert bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                enable_on_install=True) == {"FINISHED"}
assert "bl_ext.user_default.blender_mrvm" in sys.modules and hasattr(bpy.types, "MRVM_OT_render_dataset")
bpy.ops.mesh.primitive_torus_add()
props = bpy.context.scene.mrvm_dataset
props.output_dir, props.views, props.resolution, props.samples = str(out), 2, 24, 1
assert bpy.ops.mrvm.render_dataset() == {"FINISHED"}, props.status
meta = json.loads((out / "custom" / "Torus" / "meta.json").read_text())
print("rendered", meta["complete"], meta["n_views"], bpy.app.version_string)
"""


@pytest.mark.slow
def test_the_extension_zip_installs_into_this_blender_and_renders(tmp_path):
    """What a user does: install the built zip (Get Extensions > Install from Disk), then render a dataset from the
    panel's operator, in a fresh Blender with a user folder of its own. Under Blender 4.2 (make test-blender) this
    is the check that the extension runs on the oldest Blender its manifest names."""
    import os
    import subprocess
    import sys

    from blender_mrvm.commands.build_extension import build, validate

    zip_path = build(tmp_path / "dist")
    validate(zip_path)
    home = tmp_path / "home"
    home.mkdir()
    env = {**os.environ, "HOME": str(home), "XDG_CONFIG_HOME": str(home / ".config"),
           "BLENDER_USER_RESOURCES": str(home / "blender")}
    env.pop("PYTHONPATH", None)  # the installed extension, not the working tree, is what runs
    res = subprocess.run([sys.executable, "-c", _INSTALL_AND_RENDER, str(zip_path), str(tmp_path / "ds")],
                         capture_output=True, text=True, env=env, cwd=home, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "rendered True 2" in res.stdout, res.stdout[-2000:]


# Blender's own Python has numpy and a few packages of its own, none of the project venv's others. The test runs
# Blender (as a module, in the venv) with the venv's other packages hidden, so what the extension runs inside
# Blender must come from Blender or from the wheels the zip bundles (installed into the extensions' site-packages).
_IN_BLENDERS_OWN_PYTHON = """
import importlib.abc, importlib.machinery, json, sys
from pathlib import Path
zip_path, work = sys.argv[-2], Path(sys.argv[-1])
HIDDEN = {"PIL", "OpenEXR", "Imath", "scipy", "trimesh", "torch", "pycolmap", "pillow_heif", "av", "safetensors",
          "tqdm", "skimage", "pybullet", "assimp_py", "hypothesis", "pytest"}
EXTENSIONS = str(work / "home")


class Hide(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] not in HIDDEN:
            return None
        if path is None:  # a top-level package: only where the extension's wheels are installed
            path = [p for p in sys.path if p.startswith(EXTENSIONS)]
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is not None and (spec.origin or "").startswith(EXTENSIONS):
            return spec  # a bundled wheel, installed with the extension
        raise ModuleNotFoundError(f"No module named {name!r} (not in Blender's Python)", name=name)


sys.meta_path.insert(0, Hide())
import bpy
assert bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                enable_on_install=True) == {"FINISHED"}
import bl_ext.user_default.blender_mrvm as ext
from bl_ext.user_default.blender_mrvm.datasets import format as F
from bl_ext.user_default.blender_mrvm.scene import novel_views as NV
bpy.ops.mesh.primitive_torus_add()
props = bpy.context.scene.mrvm_dataset
props.output_dir, props.views, props.resolution, props.samples = str(work / "ds"), 2, 64, 1
assert bpy.ops.mrvm.render_dataset() == {"FINISHED"}, props.status  # selected objects: EXR and PNG
props.source, props.source_path = "PATH", str(work / "box.off")  # OFF: read with trimesh
assert bpy.ops.mrvm.render_dataset() == {"FINISHED"}, props.status
for name in ("Torus", "box"):
    ov = F.read_object(work / "ds" / "custom" / name)
    depth = F.read_depth(work / "ds" / "custom" / name / "depth" / "000000.exr")
    assert ov.meta["complete"] and ov.mask(0).any() and ((depth > 0) == (ov.mask(0) > 0)).all()
r = bpy.context.scene.render
r.resolution_x, r.resolution_y, r.resolution_percentage = 64, 64, 100  # the views' frame
cams = NV.add_reference_cameras(bpy.context.scene, work / "ds" / "custom" / "box", (0, 1))
folder, views = NV.export_scene_references(bpy.context.scene, cams, work / "refs")  # PNGs read and written
assert views == (0, 1) and F.read_png(folder / "rgb" / "000001.png").shape[:2] == (64, 64)
# Novel views from the panel: the worker (the venv's Python, which has torch) renders, Blender makes the plane.
from bl_ext.user_default.blender_mrvm.scene import image_planes as IP
bpy.context.preferences.addons["bl_ext.user_default.blender_mrvm"].preferences.python_path = sys.executable
bpy.ops.wm.save_as_mainfile(filepath=str(work / "scene.blend"))
scene = bpy.context.scene
target = bpy.data.objects["MRVM reference 001"].copy()
target.name = "Target"
scene.collection.objects.link(target)
for o in scene.objects:
    o.select_set(o == target)
p = scene.mrvm_novel_views
p.reference_source, p.dataset_dir, p.reference_views = "DATASET", str(work / "ds" / "custom" / "box"), "0 1"
p.target_source, p.plane_distance = "SELECTED", 1.0
assert bpy.ops.mrvm.synthesize() == {"FINISHED"}, p.status
(plane,) = IP.planes_of(target)
assert tuple(bpy.data.images[plane["mrvm_image"]].size) == (64, 64)
# Sem2NeRF from the panel, from a library object's mask: the generator in the worker, the planes in Blender.
props.source, props.library_category, props.library_count, props.library_seed = "LIBRARY", "chair", 1, 3
props.views, props.output_dir = 1, str(work / "lib")
assert bpy.ops.mrvm.render_dataset() == {"FINISHED"}, props.status
q = scene.mrvm_sem2nerf
q.mask_source, q.mask_path = "FILE", str(work / "lib" / "chair" / "chair_000003" / "mask" / "000000.png")
q.viewpoint, q.target_source, q.orbit_count, q.output_dir = "DATASET", "ORBIT", 2, str(work / "s2n")
assert bpy.ops.mrvm.sem2nerf() == {"FINISHED"}, q.status
assert len([o for o in bpy.data.collections["MRVM Sem2NeRF"].all_objects if o.type == "MESH"]) == 2, q.status
# Poses of photos from the panel: pycolmap in the worker, the cameras and points imported in Blender.
from bl_ext.user_default.blender_mrvm.scene.capture import render_textured_ring
render_textured_ring(work / "ring", n_views=24, width=320, height=240, samples=4)
c = scene.mrvm_capture
c.images_dir, c.output_dir = str(work / "ring" / "images"), str(work / "cap")
assert bpy.ops.mrvm.recover_poses() == {"FINISHED"}, c.status
cams = [o for o in bpy.data.collections["Capture cap"].all_objects if o.type == "CAMERA"]
assert len(cams) >= 12 and all(o.data.background_images[0].image for o in cams), c.status
print("bundled", sorted(m for m in ("PIL", "OpenEXR", "trimesh", "assimp_py") if m in sys.modules))
"""


@pytest.mark.slow
def test_the_extension_works_in_blenders_own_python(tmp_path):
    """In an installed Blender the extension runs in Blender's own Python, which has none of the venv's packages
    (the tests run Blender as a module in the venv, which hid this): Render Dataset from the panel stopped on
    ``No module named 'OpenEXR'``. The zip now bundles openexr, pillow and trimesh with assimp-py; with the venv's
    packages hidden, the operator renders selected objects and an OFF file, reference cameras are read and written,
    a novel view is synthesized from the panel (the worker: the venv's Python) into an image plane, Sem2NeRF makes
    two views of a library chair's mask, and the poses of 24 photos are recovered (pycolmap in the worker) and
    imported as cameras. Needs the wheels: fetched from the package index once (.cache/extension_wheels), as set-up
    is."""
    import os
    import sys

    from blender_mrvm.commands.build_extension import WHEEL_CACHE, build, fetch_wheels

    wheels = fetch_wheels(ROOT / WHEEL_CACHE)
    zip_path = build(tmp_path / "dist", wheels)

    def run(work: Path) -> subprocess.CompletedProcess:
        """The script in a fresh folder ``work``: its Blender user folder (home/) and everything it writes."""
        (work / "home").mkdir(parents=True)
        (work / "box.off").write_text("OFF\n8 6 0\n" + "".join(f"{x} {y} {z}\n" for x in (0, 1) for y in (0, 1)
                                                                for z in (0, 1)) +
                                      "4 0 1 3 2\n4 4 6 7 5\n4 0 4 5 1\n4 2 3 7 6\n4 0 2 6 4\n4 1 5 7 3\n")
        home = work / "home"
        env = {**os.environ, "HOME": str(home), "XDG_CONFIG_HOME": str(home / ".config"),
               "BLENDER_USER_RESOURCES": str(home / "blender"), "PYTHONFAULTHANDLER": "1", "PYTHONUNBUFFERED": "1"}
        env.pop("PYTHONPATH", None)
        return subprocess.run([sys.executable, "-c", _IN_BLENDERS_OWN_PYTHON, str(zip_path), str(work)],
                              capture_output=True, text=True, env=env, cwd=home, timeout=600)

    res = run(tmp_path / "run1")
    if res.returncode < 0:
        # Killed by a signal: once in about 25 runs in the full suite (session 47) this Blender process crashed
        # (SIGSEGV) after its first render; never in 12 runs on its own, and the cause is not found. One rerun, with
        # the crash's stack (faulthandler) kept as a warning, so a crash that repeats still fails the test.
        import warnings

        warnings.warn(f"Blender crashed (signal {-res.returncode}) in the installed-extension run; rerun once. "
                      f"stderr: {res.stderr[-3000:]}")
        res = run(tmp_path / "run2")
    assert res.returncode == 0, res.stderr[-4000:]
    assert "bundled ['OpenEXR', 'PIL', 'assimp_py', 'trimesh']" in res.stdout, res.stdout[-2000:]


def test_relative_imports_only():
    bad = []
    for f in (ROOT / "blender_mrvm").rglob("*.py"):
        for k, line in enumerate(f.read_text().splitlines(), 1):
            s = line.strip()
            if s.startswith(("import blender_mrvm", "from blender_mrvm")):
                bad.append(f"{f.relative_to(ROOT)}:{k}")
    assert not bad, bad


@pytest.mark.slow
def test_operator_renders_selected_objects(empty_scene, tmp_path):
    import bpy

    bpy.ops.mesh.primitive_torus_add()
    props = empty_scene.mrvm_dataset
    props.output_dir = str(tmp_path / "ds")
    props.views, props.resolution, props.samples = 2, 24, 1
    assert bpy.ops.mrvm.render_dataset() == {"FINISHED"}
    meta = json.loads((tmp_path / "ds" / "custom" / "Torus" / "meta.json").read_text())
    assert meta["complete"] and meta["n_views"] == 2
    assert "2 views rendered" in props.status


@pytest.mark.slow
def test_operator_renders_library_objects(empty_scene, tmp_path):
    import bpy

    props = empty_scene.mrvm_dataset
    props.source, props.library_category, props.library_count, props.library_seed = "LIBRARY", "chair", 2, 5
    props.output_dir = str(tmp_path / "ds")
    props.views, props.resolution, props.samples = 1, 16, 1
    assert bpy.ops.mrvm.render_dataset() == {"FINISHED"}
    assert sorted(p.name for p in (tmp_path / "ds" / "chair").iterdir()) == ["chair_000005", "chair_000006"]
    meta = json.loads((tmp_path / "ds" / "chair" / "chair_000005" / "meta.json").read_text())
    assert "chair/seat" in meta["labels"].values()


def test_operator_reports_errors_and_leaves_scene(empty_scene, tmp_path):
    import bpy

    props = empty_scene.mrvm_dataset
    props.output_dir = str(tmp_path / "ds")
    n = len(bpy.data.objects), len(bpy.data.scenes)
    with pytest.raises(RuntimeError, match=r"poll\(\) Select the objects to render \(meshes, curves, surfaces, texts "
                                           r"or metaballs\)"):  # the button is greyed out, with the reason
        bpy.ops.mrvm.render_dataset()
    props.source, props.source_path = "PATH", str(tmp_path / "missing.obj")
    with pytest.raises(RuntimeError, match="mesh file or folder not found"):
        bpy.ops.mrvm.render_dataset()
    assert (len(bpy.data.objects), len(bpy.data.scenes)) == n and not (tmp_path / "ds").exists()


@pytest.mark.slow
def test_operator_warns_of_a_missing_texture(empty_scene, tmp_path):
    """The panel says what the CLI's warning line says: a mesh's texture that is not there was dropped."""
    import shutil

    import bpy

    pybullet_data = pytest.importorskip("pybullet_data")
    for f in ("duck.obj", "duck.mtl"):  # without duckCM.png
        shutil.copy(Path(pybullet_data.getDataPath()) / f, tmp_path / f)
    props = empty_scene.mrvm_dataset
    props.source, props.source_path = "PATH", str(tmp_path / "duck.obj")
    props.output_dir = str(tmp_path / "ds")
    props.views, props.resolution, props.samples = 1, 16, 1
    assert bpy.ops.mrvm.render_dataset() == {"FINISHED"}
    assert "1 views rendered" in props.status and "warning:" in props.status and "duckCM.png" in props.status


class _RecordingLayout:
    """Stands in for bpy's UILayout (headless Blender draws no UI): records what a panel draws."""

    def __init__(self, log):
        self.log, self.enabled, self.active = log, True, True
        self.use_property_split = self.use_property_decorate = False

    def _child(self, *a, **k):
        return _RecordingLayout(self.log)

    column = row = box = split = _child

    def prop(self, data, name, **k):
        self.log.append(("prop", name))

    def operator(self, idname, **k):
        self.log.append(("operator", idname))
        return type("OpProps", (), {})()

    def label(self, text="", **k):
        self.log.append(("label", text))

    def progress(self, factor=0.0, text="", **k):
        self.log.append(("progress", text))

    def separator(self, *a, **k):
        pass


def test_every_panel_draws_idle_and_running(empty_scene):
    import types

    import bpy

    panels = [c for c in bpy.types.Panel.__subclasses__() if c.__name__.startswith("MRVM_PT_")]
    assert len(panels) >= 5
    for running in (False, True):
        for name in ("mrvm_dataset", "mrvm_capture", "mrvm_novel_views", "mrvm_train", "mrvm_sem2nerf"):
            props = getattr(empty_scene, name)
            props.running, props.status = running, "halfway through a long job"
        for cls in panels:
            if hasattr(cls, "poll") and not cls.poll(bpy.context):
                continue
            log: list = []
            cls.draw(types.SimpleNamespace(layout=_RecordingLayout(log)), bpy.context)
            ops = [e[1] for e in log if e[0] == "operator"]
            if running and cls.__name__ != "MRVM_PT_main":
                assert ("label", "Press Esc to cancel") in log, cls.__name__
                assert ("progress", "halfway through a long job") in log, cls.__name__
            elif ops:
                assert ("label", "halfway through a long job") in log, cls.__name__
    for name in ("mrvm_dataset", "mrvm_capture", "mrvm_novel_views", "mrvm_train", "mrvm_sem2nerf"):
        getattr(empty_scene, name).running = False


def test_one_zip_names_the_platforms_its_wheels_cover(tmp_path):
    """build-extension without --split-platforms: the manifest's ``platforms`` are those on which every bundled
    package has a wheel, so Blender refuses to install it elsewhere (macOS x64, Windows ARM: pillow and openexr have
    no wheels there in the bundled set) instead of installing it without them. Before, it named none. Only pure
    wheels (or none): no ``platforms``, i.e. every platform."""
    import os
    import sys

    import bpy

    from blender_mrvm.commands import build_extension as B

    sys.path.insert(0, os.path.join(bpy.utils.system_resource("SCRIPTS"), "addons_core"))
    try:
        from bl_pkg.bl_extension_utils import pkg_manifest_params_compatible_or_error
    finally:
        sys.path.pop(0)
    whl = tmp_path / "whl"
    whl.mkdir()
    wheels = [_fake_wheel(whl, py, plat, "binpkg") for py in ("cp311", "cp313")
              for plat in ("win_amd64", "macosx_11_0_arm64", "manylinux_2_28_x86_64", "manylinux_2_28_aarch64")]
    wheels += [_fake_wheel(whl, py, plat, "otherpkg") for py in ("cp311", "cp313")
               for plat in ("win_amd64", "win_arm64", "macosx_10_9_universal2",
                            "manylinux_2_17_x86_64.manylinux2014_x86_64")]  # no linux-arm64
    pure = _fake_wheel(whl, name="purepkg")
    assert B.wheel_platforms([*wheels, pure]) == ["windows-x64", "macos-arm64", "linux-x64"]
    manifest = tomllib.loads(zipfile.ZipFile(B.build(tmp_path / "out", [*wheels, pure]))
                             .read("blender_manifest.toml").decode())
    assert manifest["platforms"] == ["windows-x64", "macos-arm64", "linux-x64"]
    refused = {plat: pkg_manifest_params_compatible_or_error(
                   blender_version_min=manifest["blender_version_min"], blender_version_max="",
                   platforms=manifest["platforms"], python_versions=["3.11", "3.13"], this_platform=plat,
                   this_python_version=(3, 11, 9), this_blender_version=(4, 2, 0), error_fn=print) is not None
               for plat in B.ALL_BLENDER_PLATFORMS}
    assert refused == {"windows-x64": False, "windows-arm64": True, "macos-x64": True, "macos-arm64": False,
                       "linux-x64": False, "linux-arm64": True}
    only_pure = tomllib.loads(zipfile.ZipFile(B.build(tmp_path / "pure", [pure]))
                              .read("blender_manifest.toml").decode())
    assert "platforms" not in only_pure and B.wheel_platforms([]) == list(B.ALL_BLENDER_PLATFORMS)
    # the real set (the cache --wheels auto fills), where it was fetched: every package on the four platforms
    real = B.bundled_in(B.WHEEL_CACHE / "py3.11-win_amd64")
    if real:
        cached = [w for folder in B.WHEEL_CACHE.glob("py3.*") for w in B.bundled_in(folder)]
        assert B.wheel_platforms(cached) == ["windows-x64", "macos-arm64", "linux-x64", "linux-arm64"]


def test_the_wheel_cache_is_the_repositorys_wherever_the_command_runs(tmp_path, monkeypatch):
    """build-extension --wheels auto keeps its downloads in the repository's .cache/extension_wheels; before, in
    ./.cache of whatever folder the command ran from (a new download and a stray folder each time)."""
    import types

    from blender_mrvm.commands import build_extension as B
    from blender_mrvm.errors import MRVMError

    assert B.WHEEL_CACHE == ROOT / ".cache" / "extension_wheels"
    asked = []

    def offline(dest):
        asked.append(Path(dest))
        raise MRVMError("offline")

    def stop(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(B, "fetch_wheels", offline)
    monkeypatch.setattr(B, "build", stop)
    monkeypatch.chdir(tmp_path)
    # Offline, nothing is built (it built a zip without its wheels, exit 0: a release job could not tell)
    with pytest.raises(MRVMError, match=r"^offline; nothing was built: .*--wheels DIR.*--wheels none"):
        B.run(types.SimpleNamespace(out=str(tmp_path / "dist"), wheels="auto", split_platforms=False))
    assert [p.resolve() for p in asked] == [ROOT / ".cache" / "extension_wheels"]
    assert not list((tmp_path / "dist").glob("*.zip"))


def test_the_manifest_asks_for_the_clipboard():
    """prefs.py's Copy Install Command writes the clipboard: the manifest says so (Blender's rule: a short reason
    without a trailing period; test_extension_zip validates the manifest with Blender's own validator)."""
    manifest = tomllib.loads((ROOT / "blender_mrvm" / "blender_manifest.toml").read_text())
    reason = manifest["permissions"]["clipboard"]
    assert reason and len(reason) <= 64 and reason[-1].isalnum()
    assert "context.window_manager.clipboard" in (ROOT / "blender_mrvm" / "prefs.py").read_text()


def test_shipped_model_choices_keep_their_numbers_in_saved_files(empty_scene, tmp_path):
    """A .blend stores an enum choice as its item's number, which without one is its position: inserting "auto"
    first made files saved before open on the next model up (a saved 'gpnr' came back as 'nerformer_mrvm'). The
    numbers are pinned: a new model is appended with a new number, never inserted."""
    import bpy

    from blender_mrvm.props import SHIPPED_MODELS

    pinned = {"auto": 0, "nerformer_mrvm": 1, "gpnr": 2, "gpnr_captures": 3, "mrvm_anyview": 4, "mrvm_quality": 5}
    assert {i[0]: i[3] for i in SHIPPED_MODELS if i[0] in pinned} == pinned
    numbers = [i[3] for i in SHIPPED_MODELS]
    assert len(set(numbers)) == len(numbers)
    empty_scene.mrvm_novel_views.shipped_model = "gpnr"
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "s.blend"))
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "s.blend"))
    assert bpy.context.scene.mrvm_novel_views.shipped_model == "gpnr"


def test_save_as_elsewhere_keeps_the_panels_paths_on_the_same_folders(empty_scene, tmp_path):
    """Save As into another folder left the panel's // paths as typed, so they named folders beside the new .blend:
    Render Dataset rendered a whole new dataset there instead of resuming, Synthesize looked for its references there.
    They are rebased as Blender's Remap Relative does for images: the same folders, from the new file; a Save Copy
    rebases the copy only; a save into the same folder changes nothing."""
    import os

    import bpy

    d, nv = empty_scene.mrvm_dataset, empty_scene.mrvm_novel_views
    (tmp_path / "p1").mkdir()
    (tmp_path / "p2" / "sub").mkdir(parents=True)
    (tmp_path / "p3").mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "p1" / "s.blend"))
    d.output_dir, nv.dataset_dir, nv.checkpoint = "//mrvm_dataset", "//mrvm_dataset/chair/c0/", "/abs/run"
    where = {k: bpy.path.abspath(v) for k, v in (("out", d.output_dir), ("refs", nv.dataset_dir))}
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "p1" / "s2.blend"))
    assert d.output_dir == "//mrvm_dataset"  # the same folder: as typed
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "p2" / "sub" / "t.blend"))
    assert d.output_dir == "//../../p1/mrvm_dataset" and nv.dataset_dir == "//../../p1/mrvm_dataset/chair/c0/"
    assert os.path.normpath(bpy.path.abspath(d.output_dir)) == os.path.normpath(where["out"])
    assert nv.checkpoint == "/abs/run"
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "p3" / "c.blend"), copy=True)
    assert d.output_dir == "//../../p1/mrvm_dataset", "the open file is still t.blend"
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "p3" / "c.blend"))
    assert bpy.context.scene.mrvm_dataset.output_dir == "//../p1/mrvm_dataset"


def test_wheels_folder_in_the_caches_layout_builds_offline(tmp_path, capsys):
    """install.md's offline build, `--wheels .cache/extension_wheels`, failed: the cache keeps a subfolder a Python and
    platform, and --wheels read only loose wheels ('not a folder of .whl files'), or, where older loose wheels lay
    beside the subfolders, bundled those instead. Subfolders are taken in place of loose wheels."""
    from blender_mrvm.cli import main

    cache = tmp_path / "extension_wheels"
    for sub, name in (("py3.11-manylinux_2_28_x86_64", "demo_pkg-1.0-cp311-cp311-manylinux_2_28_x86_64.whl"),
                      ("py3.13-manylinux_2_28_x86_64", "demo_pkg-1.0-cp313-cp313-manylinux_2_28_x86_64.whl"),
                      ("py3.11-manylinux_2_28_x86_64", "pure_pkg-2.0-py3-none-any.whl"),
                      ("py3.13-manylinux_2_28_x86_64", "pure_pkg-2.0-py3-none-any.whl")):
        (cache / sub).mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(cache / sub / name, "w") as z:
            z.writestr("x.txt", "x")
    with zipfile.ZipFile(cache / "stale_pkg-0.1-py3-none-any.whl", "w") as z:
        z.writestr("x.txt", "x")
    assert main(["build-extension", "--out", str(tmp_path / "d"), "--wheels", str(cache)]) == 0
    (zip_path,) = (tmp_path / "d").glob("*.zip")
    m = tomllib.loads(zipfile.ZipFile(zip_path).read("blender_manifest.toml").decode())
    names = sorted(Path(w).name for w in m["wheels"])
    assert names == ["demo_pkg-1.0-cp311-cp311-manylinux_2_28_x86_64.whl",
                     "demo_pkg-1.0-cp313-cp313-manylinux_2_28_x86_64.whl", "pure_pkg-2.0-py3-none-any.whl"], names
