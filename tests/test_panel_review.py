"""The sidebar panel as a first-time artist meets it (headless): every setting has a tooltip; the shipped models'
tooltips carry their measured figures from the one place that holds them; limits and defaults agree with the
CLI's; a button the settings or the scene cannot run is greyed out with a reason instead of failing when pressed;
messages name the panel's controls, not the CLI's flags."""

from __future__ import annotations

import math
import types

import pytest

from blender_mrvm.errors import InputError
from tests.test_novel_views import FakeLayout

INTERNAL = {"rna_type", "name", "running", "progress", "status"}
"""A section's job state: never drawn as a setting."""


def _groups():
    from blender_mrvm import props as P

    return P.SCENE_PROPERTIES.items()


def _poll_reason(op) -> str:
    """'' when the operator can run now, else the reason its greyed-out button gives."""
    if op.poll():
        return ""
    with pytest.raises(RuntimeError) as e:
        op()
    msg = str(e.value)
    assert "poll()" in msg, msg
    return msg.split("poll()", 1)[1].strip()


def test_every_setting_an_artist_sees_has_a_tooltip(empty_scene):
    """Hovering any control of the panel says what it does (an enum's own tooltip, not only its items')."""
    missing = [f"{name}.{prop.identifier}" for name, cls in _groups() for prop in cls.bl_rna.properties
               if prop.identifier not in INTERNAL and not prop.description.strip()]
    assert not missing, f"settings without a tooltip: {missing}"
    from blender_mrvm.props import MRVM_PG_dataset

    assert MRVM_PG_dataset.bl_rna.properties["resolution"].subtype == "PIXEL"  # shown with its unit, px


def test_shipped_model_tooltips_carry_the_measured_figures(empty_scene):
    """Each shipped model's tooltip ends with its seconds per view and PSNR / LPIPS, read from
    ``models.pretrained.FIGURES`` (what the line under the choice shows), not written again by hand; no tooltip
    says less than the figures ("slightly worse" for 2.6 dB)."""
    from blender_mrvm.models.pretrained import FIGURES
    from blender_mrvm.props import SHIPPED_MODELS

    for key, _name, desc, *_ in SHIPPED_MODELS:
        assert key in FIGURES, f"the shipped model {key!r} has no measured figures"
        assert desc.endswith(FIGURES[key]), key
        assert "slightly worse" not in desc, key
    import bpy

    items = bpy.types.Scene.bl_rna.properties["mrvm_novel_views"].fixed_type.properties["shipped_model"].enum_items
    assert FIGURES["mrvm_anyview"] in items["mrvm_anyview"].description  # what Blender shows


def test_limits_and_defaults_agree_with_the_cli(empty_scene):
    """The panel refuses nothing the CLI takes and takes nothing the CLI refuses; its defaults are the CLI's where
    the two have the same setting (the differences kept are listed in the review's report)."""
    import argparse

    from blender_mrvm.capture.config import CaptureConfig
    from blender_mrvm.commands import render_dataset as RD
    from blender_mrvm.commands import synthesize as SY
    from blender_mrvm.scene.render import MAX_RESOLUTION, MAX_VIEWS
    from blender_mrvm.validation import MAX_REFERENCE_SIDE

    s = empty_scene
    nv, ds, cap = s.mrvm_novel_views, s.mrvm_dataset, s.mrvm_capture
    rna = lambda g, k: g.bl_rna.properties[k]  # noqa: E731
    assert rna(nv, "reference_size").hard_max == MAX_REFERENCE_SIDE  # --ref-size is at most 4096
    assert rna(ds, "views").hard_max == MAX_VIEWS and rna(ds, "resolution").hard_max == MAX_RESOLUTION
    assert rna(nv, "orbit_count").hard_max == 10000  # synthesize --orbit: 1 to 10000
    from blender_mrvm.datasets.novel_views import MAX_REFERENCES

    assert rna(nv, "nearest").hard_max == MAX_REFERENCES
    # Defaults, where the CLI has the same setting.
    p = argparse.ArgumentParser()
    RD.add_arguments(p)
    a = p.parse_args(["--source", "x", "--out", "y"])
    assert (ds.rig, ds.views, ds.resolution, ds.engine, ds.samples, ds.seed, ds.rgba) == (
        a.rig, a.views, int(a.resolution), a.engine, a.samples, a.seed, a.rgba)
    assert math.isclose(math.degrees(ds.fov), a.fov, abs_tol=1e-4)
    assert math.isclose(math.degrees(ds.elevation), a.elevation, abs_tol=1e-4)
    p = argparse.ArgumentParser()
    SY.add_arguments(p)
    a = p.parse_args(["--references", "r", "--orbit", "8", "--out", "o"])
    assert (nv.nearest, nv.photo_colours.lower(), nv.quality.lower(), nv.precision.lower(), nv.device.lower(),
            nv.adapt_steps, nv.reference_sizing) == (a.nearest, a.reproject, a.quality, a.precision, a.device,
                                                     a.adapt_steps, "AUTO" if a.ref_size == 0 else "?")
    assert math.isclose(math.degrees(nv.orbit_elevation), 20.0, abs_tol=1e-4)  # --orbit-elevation's default 20
    d = CaptureConfig()
    assert (cap.camera_model, cap.matcher, cap.max_features, cap.upsample_below, cap.single_camera,
            cap.estimate_focal, cap.allow_pair, cap.video_frames) == (
        d.camera_model, d.matcher, d.max_num_features, d.upsample_below, d.single_camera, d.estimate_focal,
        d.allow_pair, d.video_frames)


def test_buttons_are_greyed_out_with_a_reason_on_a_fresh_scene(empty_scene, tmp_path):
    """A fresh, unsaved scene: each section's button is greyed out (poll) and says what to do, instead of being
    pressable and then failing; once the settings and the scene allow it, it can be pressed."""
    import bpy

    ops = bpy.ops.mrvm
    s = empty_scene
    # Dataset: "Selected objects" with nothing selected; then a curve is selected (it renders too), but the default
    # Output (//mrvm_dataset) needs a saved .blend.
    assert "Select the objects to render" in _poll_reason(ops.render_dataset)
    curve = bpy.data.objects.new("Curve", bpy.data.curves.new("Curve", "CURVE"))
    s.collection.objects.link(curve)
    curve.select_set(True)
    assert "Save the .blend first: Output is relative to it" in _poll_reason(ops.render_dataset)
    s.mrvm_dataset.output_dir = str(tmp_path / "ds")
    assert _poll_reason(ops.render_dataset) == ""
    s.mrvm_dataset.rig = "scene"
    assert "add a camera" in _poll_reason(ops.render_dataset)
    # The panel counts what Render Dataset renders: the curve too.
    from blender_mrvm.panels.main import MRVM_PT_dataset

    log = _draw(MRVM_PT_dataset)
    assert ("label", "1 object to render selected", "OBJECT_DATA") in log
    # Capture: no photos chosen.
    assert "Choose the Photos" in _poll_reason(ops.recover_poses)
    s.mrvm_capture.images_dir = str(tmp_path)
    assert "Save the .blend first: Output" in _poll_reason(ops.recover_poses)
    s.mrvm_capture.output_dir = str(tmp_path / "cap")
    assert _poll_reason(ops.recover_poses) == ""
    # Novel views: no object folder; then targets "Selected cameras" with none selected.
    nv = s.mrvm_novel_views
    assert "Choose the references' Object folder" in _poll_reason(ops.synthesize)
    nv.dataset_dir = str(tmp_path)
    assert "Save the .blend first: Output" in _poll_reason(ops.synthesize)
    nv.output = "PACK"
    assert _poll_reason(ops.synthesize) == ""
    nv.target_source = "SELECTED"
    assert "Select the target cameras" in _poll_reason(ops.synthesize)
    nv.reference_source = "SCENE"
    assert "No scene camera has a reference image" in _poll_reason(ops.synthesize)
    # Sem2NeRF: no mask chosen; a painted mask needs its camera.
    sn = s.mrvm_sem2nerf
    assert "Choose the Mask file" in _poll_reason(ops.sem2nerf)
    sn.mask_source = "IMAGE"
    sn.mask_image = bpy.data.images.new("mask", 8, 8)
    assert "Choose the camera the mask is seen from" in _poll_reason(ops.sem2nerf)
    # Training: the default Dataset and Run folder are relative to an unsaved .blend.
    assert "Save the .blend first: Dataset is relative to it" in _poll_reason(ops.train)
    s.mrvm_train.data_dir, s.mrvm_train.run_dir = str(tmp_path), str(tmp_path / "run")
    assert _poll_reason(ops.train) == ""
    s.mrvm_train.start_from = "CHECKPOINT"
    assert "choose the checkpoint to fine-tune" in _poll_reason(ops.train)


def _draw(panel_cls):
    import bpy

    layout = FakeLayout()
    panel_cls.draw(types.SimpleNamespace(layout=layout), bpy.context)
    return layout.log


def _fake_job(monkeypatch, module, error=None, note=""):
    """Make ``module``'s operator fail at its check with ``error``, or finish with ``note`` as its message, without
    a worker."""
    from blender_mrvm.progress import Progress

    def plan(context):
        if error:
            raise InputError(error)
        return None

    def run(*a, **k):
        yield Progress(0, 1, "starting")
        return None

    monkeypatch.setattr(module, "plan_from_props", plan)
    monkeypatch.setattr(module, "prepare", lambda *a, **k: None)
    monkeypatch.setattr(module, "run_job", run)
    for name in ("import_run", "on_train_result"):
        if hasattr(module, name):
            monkeypatch.setattr(module, name, lambda *a, **k: note)


def test_messages_name_the_panels_controls_not_the_clis_flags(empty_scene, tmp_path, monkeypatch):
    """The CLI's code checks the panel's settings too (in Blender and in the worker), and its messages name its
    flags (`--ref-size`, `--adapt-steps`, `--no-resume --force`): the panel says its own controls' names instead;
    a command the artist is told to run stays as it is."""
    import bpy

    from blender_mrvm.operators import synthesize as SY
    from blender_mrvm.operators import train as TR

    nv = empty_scene.mrvm_novel_views
    nv.dataset_dir, nv.output = str(tmp_path), "PACK"
    # An error from the references' memory check (validation.check_reference_memory's words).
    _fake_job(monkeypatch, SY, error="2 reference views at 8000x8000 take 4.8 GiB of memory, over the 4 GiB limit "
                                     "for references; pass --ref-size 3600 or smaller (their longer side in pixels; "
                                     "in the panel: Reference size Custom), or choose fewer with --views")
    with pytest.raises(RuntimeError):
        bpy.ops.mrvm.synthesize()
    assert "--" not in nv.status and "'Reference size' 3600" in nv.status and "'Views'" in nv.status, nv.status
    # A finished run's note (training.adapt.few_references_note).
    _fake_job(monkeypatch, SY, note="3 novel views; Note: adapting to 2 references: ... consider --adapt-steps 0")
    bpy.ops.mrvm.synthesize()
    assert nv.status.endswith("consider 'Adapt steps' 0"), nv.status
    # Training: the run folder's refusal (training.run_folder) and the weights' hint (a command to run).
    tr = empty_scene.mrvm_train
    tr.data_dir, tr.run_dir = str(tmp_path), str(tmp_path / "run")
    _fake_job(monkeypatch, TR, error="the run folder holds a run of another model; start it over (--no-resume "
                                     "--force) or give another --out")
    with pytest.raises(RuntimeError):
        bpy.ops.mrvm.train()
    assert "--" not in tr.status and "'Continue run' off and 'Replace the run' ticked" in tr.status, tr.status
    assert "another 'Run folder'" in tr.status
    _fake_job(monkeypatch, TR, error='the LPIPS loss needs the offline weights: run `python -m blender_mrvm '
                                     'fetch-weights --out "/w"` once')
    with pytest.raises(RuntimeError):
        bpy.ops.mrvm.train()
    assert '`python -m blender_mrvm fetch-weights --out "/w"`' in tr.status, tr.status
    # The render's own "(in the panel: ...)" hints read once, in the panel's words.
    ds = empty_scene.mrvm_dataset
    ds.source, ds.source_path, ds.output_dir = "PATH", str(tmp_path / "x.obj"), str(tmp_path / "ds")
    from blender_mrvm.operators import dataset as DS

    def refuse(context):
        raise InputError(f"{tmp_path / 'ds'} holds another dataset; use --force (in the panel: Overwrite) to "
                         "overwrite it or choose another folder")

    monkeypatch.setattr(DS, "config_from_props", refuse)
    with pytest.raises(RuntimeError):
        bpy.ops.mrvm.render_dataset()
    assert "; use Overwrite to overwrite it" in ds.status and "--" not in ds.status, ds.status


def test_no_checkpoint_message_names_the_panels_training(empty_scene, monkeypatch):
    """A copy without the shipped model: the message points at the panel's Train / Fine-tune, not a shell command."""
    import bpy

    from blender_mrvm.operators import synthesize as SY

    monkeypatch.setattr(SY, "default_checkpoint", lambda kind=None: None)
    nv = empty_scene.mrvm_novel_views
    for choice in ("auto", "gpnr"):
        nv.shipped_model = choice
        with pytest.raises(InputError) as e:
            SY._checkpoint(bpy.context, nv)
        assert "python -m" not in str(e.value) and "Train / Fine-tune" in str(e.value), str(e.value)


def test_the_shipped_models_figures_fit_the_sidebar(empty_scene):
    """A label is cut off at the sidebar's edge, never wrapped: the measured figures under the model choice (400-750
    characters) are drawn over lines as wide as the panel's status lines (``wrap_text``), all of them there."""
    from blender_mrvm.models.pretrained import FIGURES, shipped_or_none
    from blender_mrvm.panels.novel_views import MRVM_PT_novel_views

    nv = empty_scene.mrvm_novel_views
    nv.checkpoint = ""
    for key in ("auto", "mrvm_anyview", "mrvm_quality"):
        if shipped_or_none(None if key == "auto" else key) is None:
            continue
        nv.shipped_model = key
        labels = [e[1] for e in _draw(MRVM_PT_novel_views) if e[0] == "label"]
        assert max(map(len, labels)) <= 48, [x for x in labels if len(x) > 48]
        assert FIGURES[key] in " ".join(labels), key


def test_autos_choice_names_the_model_as_the_panel_does(tmp_path):
    """The finish message says which model Auto picked (``synthesis.json``'s ``model_choice``,
    ``models.pretrained.auto_model``'s words) by the name the panel's Shipped model list gives it, not the CLI's
    ``shipped:mrvm_anyview``."""
    import json

    from blender_mrvm.operators.synthesize import run_note

    cases = (("auto: the any-view model (shipped:mrvm_anyview): 8 of 8 cameras are off the default model's turntable "
              "(elevation 20 degrees); shipped:mrvm_quality is sharper there on library-like objects",
              ("the any-view model ('NeRFormer + MRVM, any viewpoint')",
               "'NeRFormer + MRVM, quality' is sharper there")),
             ("auto: GPNR for rooms and captures (shipped:gpnr_captures): the references show a whole scene",
              ("('GPNR for rooms and captures')",)))
    for text, names in cases:
        (tmp_path / "synthesis.json").write_text(json.dumps({"model_choice": text}))
        note = run_note(tmp_path)
        assert "shipped:" not in note and all(n in note for n in names), note


def test_the_default_planes_float_between_the_orbit_and_the_object(empty_scene):
    """Fresh scene, default orbit (round the 3D cursor, where the object is): the planes stand where the CLI's rule
    puts them (``synthesize --blend``: half the depth of the object's centre), not through the object's middle (2.0
    with the orbit's radius 2.0: half the object in front of its own novel view in the viewport)."""
    from blender_mrvm.scene import novel_views as NV

    nv = empty_scene.mrvm_novel_views
    c = tuple(empty_scene.cursor.location)
    targets = NV.orbit_targets(empty_scene, nv.orbit_count, nv.orbit_radius, nv.orbit_elevation, nv.orbit_fov, c)
    box = (tuple(v - 0.5 for v in c), tuple(v + 0.5 for v in c))
    assert math.isclose(nv.plane_distance, NV.default_plane_distance(targets, box), rel_tol=1e-3)


def test_the_turntable_figures_of_the_finish_note_are_the_dropdowns():
    """viewpoint_note (the panel's finish message and synthesize's note) quoted the any-view model's turntable figure
    of stage 3 (19.8 dB) while the dropdown said the shipped stage 5's 20.3: one figure, as FIGURES states it."""
    from blender_mrvm.models.pretrained import FIGURES, TURNTABLE_HELD_OUT

    default = TURNTABLE_HELD_OUT["nerformer_mrvm"][0]
    for name in ("mrvm_anyview", "mrvm_quality"):
        psnr = TURNTABLE_HELD_OUT[name][0]
        assert f"{psnr:.1f}" in FIGURES[name] and f"{default:.1f}" in FIGURES[name], name
