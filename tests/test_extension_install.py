"""The add-on as an installed extension meets it: enabled after a file is opened, preferences that say what they
do, the offline weights where `fetch-weights` put them, and path settings that take ``//``."""

from __future__ import annotations

import types
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_a_file_saved_while_a_job_ran_opens_idle_when_the_addon_is_enabled_after_it(empty_scene, tmp_path):
    """Saved while a job ran, opened with the add-on disabled, then the add-on enabled: no load_post of the add-on
    saw the file, so before, its sections stayed "running" (a progress bar, "already running" at every press). The
    add-on now resets them once just after it registers (a timer: bpy.data is restricted while Blender registers
    add-ons), except the sections of jobs started since."""
    import addon_utils
    import bpy

    from blender_mrvm import props as P
    from blender_mrvm.operators import _modal

    s = empty_scene
    s.mrvm_dataset.running, s.mrvm_dataset.progress, s.mrvm_dataset.status = True, 0.4, "rendering view 3/7"
    s.mrvm_train.running = True
    blend = tmp_path / "saved while running.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    addon_utils.disable("blender_mrvm", default_set=True)
    try:
        bpy.ops.wm.open_mainfile(filepath=str(blend))
    finally:
        assert addon_utils.enable("blender_mrvm", default_set=True, handle_error=None) is not None
    s = bpy.context.scene
    assert s.mrvm_dataset.running and s.mrvm_train.running  # nothing ran yet: bpy as a module runs no timers
    assert bpy.app.timers.is_registered(P.end_jobs_after_register)
    live = types.SimpleNamespace(_scene_uid=s.session_uid, props_attr="mrvm_train", job_name="Training")
    _modal._live.append(live)  # a job started between register() and the timer keeps its section
    try:
        P.end_jobs_after_register()  # what Blender runs next
    finally:
        _modal._live.remove(live)
    assert not s.mrvm_dataset.running and s.mrvm_dataset.progress == 0.0 and s.mrvm_dataset.status == ""
    assert s.mrvm_train.running
    P.end_jobs_after_register()
    assert not s.mrvm_train.running


def _prefs():
    import bpy

    return bpy.context.preferences.addons["blender_mrvm"].preferences


@pytest.fixture
def cache_pref(addon):
    pr = _prefs()
    before = pr.cache_dir
    yield pr
    pr.cache_dir = before


def test_training_that_needs_the_offline_weights_is_refused_before_it_starts(empty_scene, cache_pref, tmp_path):
    """Keep its losses (the shipped model's LPIPS loss) and VGG16-encoder models need the offline weights
    `fetch-weights` writes. The worker now reads them from the preferences' Weights cache (MRVM_WEIGHTS_DIR); before,
    the installed extension looked beside its own folder, and the job failed in the worker after its start-up.
    Missing there, the plan refuses the job with one message naming the folder and the command that fills it."""
    import bpy

    from blender_mrvm import worker as W
    from blender_mrvm.errors import InputError
    from blender_mrvm.operators.train import plan_from_props

    (tmp_path / "data").mkdir()
    p = empty_scene.mrvm_train
    p.data_dir, p.run_dir, p.start_from, p.keep_losses = str(tmp_path / "data"), str(tmp_path / "run"), "SHIPPED", True
    empty = tmp_path / "no weights"
    empty.mkdir()
    cache_pref.cache_dir = str(empty)
    with pytest.raises(InputError) as ei:
        plan_from_props(bpy.context)
    msg = str(ei.value)
    assert msg.startswith("Keep its losses (the LPIPS loss) needs the offline VGG16 / LPIPS weights, which are not "
                          f"in {empty}: ") and f'python -m blender_mrvm fetch-weights --out "{empty}"' in msg
    assert W.worker_env()["MRVM_WEIGHTS_DIR"] == str(empty)  # where the worker would have looked
    p.keep_losses = False
    assert plan_from_props(bpy.context).init_checkpoint is not None  # no LPIPS loss: no weights needed
    p.start_from, p.preset = "NEW", "accurate"  # a VGG16 encoder from the ImageNet weights
    with pytest.raises(InputError, match=r"^the accurate size \(a VGG16 encoder\) needs the offline"):
        plan_from_props(bpy.context)
    full = tmp_path / "weights"
    full.mkdir()
    for name in W.WEIGHT_FILES:
        (full / name).write_bytes(b"x")
    cache_pref.cache_dir = str(full)
    assert plan_from_props(bpy.context).preset == "accurate"
    p.start_from, p.keep_losses = "SHIPPED", True
    assert plan_from_props(bpy.context).keep_losses
    assert W.worker_env()["MRVM_WEIGHTS_DIR"] == str(full)


def test_the_preferences_say_what_each_setting_is_for(addon, tmp_path):
    """Device is the training device only (the Novel views and Sem2NeRF panels have their own); Checkpoints was one
    default checkpoint for novel views, and a folder of runs gave the worker's "no checkpoint found" only after a
    job started: the preferences now say what they expect, under the setting."""
    import bpy

    from blender_mrvm import prefs as P

    props = P.MRVM_AddonPreferences.bl_rna.properties
    assert props["device"].name == "Training device" and "Train" in props["device"].description
    assert "Sem2NeRF" in props["device"].description
    assert props["checkpoint_dir"].name == "Default checkpoint"
    assert "folder of runs" in props["checkpoint_dir"].description
    assert props["cache_dir"].name == "Weights cache" and "fetch-weights" in props["cache_dir"].description
    runs = tmp_path / "runs"
    for run in ("a", "b"):
        (runs / run).mkdir(parents=True)
        (runs / run / "model.safetensors").write_bytes(b"x")
    note = P.checkpoint_problem(str(runs))
    assert note == (f"the default checkpoint set in the add-on preferences, {runs}, is not a checkpoint (it holds the "
                    "runs a, b: choose one): it expects a model .safetensors file, a checkpoint folder or one run "
                    "folder (holding checkpoints/)")
    assert P.checkpoint_problem(str(runs / "a")) == "" and P.checkpoint_problem("") == ""
    assert "does not exist" in P.checkpoint_problem(str(tmp_path / "nothing"))
    labels: list = []

    class Layout:
        def __getattr__(self, name):
            return lambda *a, **k: Layout()

        def label(self, text="", **k):
            labels.append(text)

    pr = types.SimpleNamespace(layout=Layout(), checkpoint_dir=str(runs))
    P.MRVM_AddonPreferences.draw(pr, bpy.context)
    assert note in labels


def test_path_settings_take_blend_relative_values_without_a_warning(empty_scene):
    """Every file and folder setting means ``//`` as relative to the .blend; Blender 4.5 and later warn at each such
    value of a path property that does not say it supports it (PATH_SUPPORTS_BLEND_RELATIVE, an option 4.2 to 4.4
    do not have: the add-on must still register there)."""
    import bpy

    from blender_mrvm import props as P

    assert P.PATH_OPTIONS == ({"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (4, 5, 0) else set())
    paths = [(name, prop.identifier) for name, cls in P.SCENE_PROPERTIES.items()
             for prop in cls.bl_rna.properties if prop.type == "STRING" and prop.subtype in ("FILE_PATH", "DIR_PATH")]
    assert len(paths) >= 14
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for name, identifier in paths:
            setattr(getattr(empty_scene, name), identifier, "//relative/path")
    assert [str(w.message) for w in caught] == []


def test_synthesize_with_a_folder_of_runs_as_the_default_checkpoint_says_what_it_expects(empty_scene, tmp_path):
    """The preferences' Default checkpoint set to a folder of runs: Synthesize gave the worker's "no checkpoint
    found at X" after the job started; it now gives the preferences' own message first."""
    import bpy

    from blender_mrvm.errors import InputError
    from blender_mrvm.operators.synthesize import _checkpoint

    runs = tmp_path / "runs"
    for run in ("a", "b"):
        (runs / run).mkdir(parents=True)
        (runs / run / "model.safetensors").write_bytes(b"x")
    pr = _prefs()
    before = pr.checkpoint_dir
    pr.checkpoint_dir = str(runs)
    try:
        p = types.SimpleNamespace(checkpoint="", shipped_model="auto")
        with pytest.raises(InputError, match="holds the runs a, b: choose one"):
            _checkpoint(bpy.context, p)
        pr.checkpoint_dir = str(runs / "a")
        assert _checkpoint(bpy.context, p) == runs / "a"
    finally:
        pr.checkpoint_dir = before
