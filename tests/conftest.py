"""Shared fixtures.

Blender tests run under the pip ``bpy`` module: the ``addon`` session fixture enables the add-on
once (``read_factory_settings`` would unregister it), and ``empty_scene`` resets the file with
``read_homefile(use_empty=True)`` before each test. Tests that need no Blender never import bpy.
"""

from __future__ import annotations

try:  # before any Blender work: under bpy 5.3 (Python 3.13, a torch with triton) importing triton after Blender
    # has evaluated or baked scenes in this process crashes it (segmentation fault: two LLVMs); torch imports it the
    # first time an optimizer is made, which the training tests do after the rendering ones
    import torch._dynamo  # noqa: F401
except Exception:  # noqa: BLE001  (torch absent or another build: nothing to pre-load)
    pass

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

os.environ.setdefault("TQDM_DISABLE", "1")

_EXIT_STATUS: list[int] = []


def pytest_sessionfinish(session, exitstatus):
    _EXIT_STATUS.append(int(exitstatus))


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """Under a bpy 4.x module (``make test-blender``), end the process once pytest is done: while the interpreter
    exits, bpy 4.2 can crash and bpy 4.5 spins for tens of minutes freeing memory, after every test ran and the
    reports were written. bpy 5.0 exits normally and is left alone."""
    bpy = sys.modules.get("bpy")
    if bpy is not None and tuple(bpy.app.version) < (5, 0, 0) and _EXIT_STATUS:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(_EXIT_STATUS[-1])


@pytest.fixture(scope="session")
def addon():
    """Enable the add-on once per session, as Blender does for an installed extension."""
    import bpy  # noqa: F401  (bpy first: it puts Blender's scripts, addon_utils among them, on sys.path)
    import addon_utils

    mod = addon_utils.enable("blender_mrvm", default_set=True, handle_error=None)
    assert mod is not None, "add-on failed to enable"
    assert hasattr(bpy.types, "MRVM_OT_render_dataset")
    yield mod


@pytest.fixture
def empty_scene(addon):
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    yield bpy.context.scene
    bpy.ops.wm.read_homefile(use_empty=True)


@pytest.fixture
def bpy_empty():
    """An empty Blender file without the add-on (pure scene-layer tests)."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    yield bpy.context.scene
    bpy.ops.wm.read_homefile(use_empty=True)


@pytest.fixture(scope="session")
def ring(tmp_path_factory):
    """The synthetic capture of issue 6, rendered once per session for test_capture*.py: (images dir, truth dict).

    24 views of a procedurally textured scene on a ring, 320x240, Cycles (about 10 s on 2 cores).
    """
    import json

    import bpy  # noqa: F401

    from blender_mrvm.scene.capture import render_textured_ring

    d = tmp_path_factory.mktemp("capture_ring")
    render_textured_ring(d, n_views=24, width=320, height=240, samples=4, threads=2)
    return d / "images", json.loads((d / "truth.json").read_text())
