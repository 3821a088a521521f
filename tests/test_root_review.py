"""A dataset root shared by runs (session 56's review of render-dataset and recover-poses as a cron job or a cluster
array runs them): what killed runs leave in the root is swept, never what a live run is writing; a run with other
settings, --force or not, is refused while another renders into the root, while shards of the same settings go on
side by side; a recover-poses run resumed after its features were extracted does the checks a fresh run does."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from blender_mrvm.cli import main
from blender_mrvm.datasets import format as F
from tests.test_output_locks import error_line, held


def _argv(out, *sources, views=1, extra=()):
    return ["render-dataset", *(a for s in sources for a in ("--source", str(s))), "--views", str(views),
            "--resolution", "8", "--samples", "1", "--engine", "BLENDER_WORKBENCH", "--out", str(out), *extra]


SOURCES = ("procedural:chair:1", "procedural:table:2")


def test_what_a_killed_run_left_in_the_root_is_swept_and_nothing_else(tmp_path, bpy_empty):
    """A run killed (SIGKILL) while writing the write probe, the root manifest or a split list left its temporary
    file in the root for good (the object folders' were swept, the root's never), and so did its registration; the
    next run removes exactly those names, not a user's file that looks like them."""
    out = tmp_path / "d"
    assert main(_argv(out, *SOURCES)) == 0
    left = [out / ".write-test-k2j4l9x_", out / f".{F.ROOT_MANIFEST}.ab12cd34.json",
            out / "splits" / ".train.lst.zz99yy88.lst", out / "splits" / ".test.lst.q_w3e4r5.lst",
            out / ".lock"]
    for p in left:
        p.write_text("{")
    dead = out / ".mrvm-run-a1b2c3d4"  # a killed run's registration: its lock file, no one holding it
    dead.mkdir()
    (dead / ".lock").write_text("999999\n")
    (dead / "run.json").write_text("{}")
    users = [out / ".write-test-notes.txt", out / f".{F.ROOT_MANIFEST}.bak", out / "splits" / ".train.lst.old"]
    for p in users:
        p.write_text("mine")
    assert main(_argv(out, *SOURCES)) == 0
    assert [p for p in left if p.exists()] == [] and not dead.exists()
    assert all(p.read_text() == "mine" for p in users)
    assert not list(out.glob(".mrvm-run-*")), "the run's own registration goes with it"


def test_a_live_runs_registration_and_the_root_it_holds_are_left_alone(tmp_path, bpy_empty, capsys, monkeypatch):
    """A shard holding the root (writing the manifest or a list) makes another wait, then give up naming it, with its
    temporary files where they were; a live run's registration is not swept."""
    from blender_mrvm.scene import render as R

    out = tmp_path / "d"
    assert main(_argv(out, *SOURCES)) == 0
    live = out / ".mrvm-run-l1v3l1v3"
    live.mkdir()
    settings = json.loads((out / F.ROOT_MANIFEST).read_text())["settings"]
    (live / "run.json").write_text(json.dumps({"pid": 4242, "host": "node7", "started": "now", "settings": settings}))
    tmp_list = out / "splits" / ".val.lst.abcdefgh.lst"
    tmp_list.write_text("being written\n")
    monkeypatch.setattr(R, "ROOT_WAIT_S", 0.3)
    with held(live):
        with held(out):
            capsys.readouterr()
            code = main(_argv(out, *SOURCES))
            line = error_line(capsys.readouterr().err)
            assert code == 2 and "in use by another process (pid 4242)" in line, line
            assert tmp_list.exists()
        assert main(_argv(out, *SOURCES, extra=("--shard", "1/2"))) == 0  # same settings: side by side
        assert live.is_dir() and (live / "run.json").is_file()
    assert not tmp_list.exists(), "swept once no run holds the root"


def test_force_with_other_settings_while_another_run_renders_is_refused_naming_it(tmp_path, bpy_empty, capsys):
    """Run A renders (suspended mid-object here: a real run, in this process); run B with --force and another seed
    replaced the root manifest under it, so A's objects were described by B's settings (a rerun of A refused, its
    objects left out of the lists). B is refused in one line naming A; a shard of A's settings goes on meanwhile; once
    A is gone, B's --force replaces the dataset."""
    from blender_mrvm.progress import run_to_end
    from blender_mrvm.scene.render import RenderConfig, render_dataset

    out = tmp_path / "d"
    a = render_dataset(RenderConfig(out=out, sources=SOURCES, views=3, resolution=(8, 8), samples=1,
                                    engine="BLENDER_WORKBENCH", shard=(0, 2)))
    try:
        next(a), next(a)  # 'starting', then A's first view is on disk
        manifest = (out / F.ROOT_MANIFEST).read_text()
        capsys.readouterr()
        code = main(_argv(out, "procedural:lamp:3", extra=("--force", "--seed", "7")))
        line = error_line(capsys.readouterr().err)
        assert code == 2 and f"pid {os.getpid()}" in line and "seed 0 != 7" in line, line
        assert (out / F.ROOT_MANIFEST).read_text() == manifest
        assert not (out / "lamp").exists()
        b = render_dataset(RenderConfig(out=out, sources=SOURCES, views=3, resolution=(8, 8), samples=1,
                                        engine="BLENDER_WORKBENCH", shard=(1, 2)))
        assert run_to_end(b).objects == ["table/table_000002"]
        run_to_end(a)
    finally:
        a.close()
    assert json.loads((out / "chair" / "chair_000001" / "meta.json").read_text())["complete"]
    assert main(_argv(out, "procedural:lamp:3", extra=("--force", "--seed", "7"))) == 0
    assert json.loads((out / F.ROOT_MANIFEST).read_text())["settings"]["seed"] == 7


def test_a_recover_poses_run_resumed_after_extraction_drops_a_bogus_exif_focal_length(tmp_path, monkeypatch):
    """A run whose features were extracted and logged without the EXIF focal-length check (a version before it, or
    one stopped between the two) and that was then killed in matching resumed straight to matching: the damaged
    prior (35 mm equivalent 65535 mm) stayed, and the mapper left out every photo. The resumed run checks the cameras
    as a fresh run does, and places the photos."""
    import pycolmap

    from blender_mrvm.capture import sfm
    from blender_mrvm.capture.config import CaptureConfig
    from blender_mrvm.progress import run_to_end
    from tests.test_capture_crashes import _exif_photos

    photos, out = _exif_photos(tmp_path / "bad", 8, 65535), tmp_path / "cap"
    cfg = CaptureConfig(num_threads=1)
    with monkeypatch.context() as m:
        m.setattr(sfm, "_drop_bogus_focal_priors", lambda db: [])  # extraction logged without the check

        def killed(*a, **k):
            raise KeyboardInterrupt
            yield

        m.setattr(sfm, "_run_in_child", killed)  # and the run stopped in matching
        with pytest.raises(KeyboardInterrupt):
            run_to_end(sfm.recover_poses(photos, out, cfg))
    assert json.loads((out / "colmap" / "stages.json").read_text())["done"] == ["extract"]
    res = run_to_end(sfm.recover_poses(photos, out, cfg))
    assert len(res.registered) >= 6, res.summary()
    db = pycolmap.Database.open(str(out / "colmap" / "database.db"))
    try:
        cams = db.read_all_cameras()
    finally:
        db.close()
    assert cams and not any(c.has_prior_focal_length for c in cams)


def test_a_recover_poses_run_killed_while_exporting_is_continued_without_force(tmp_path, capsys):
    """SIGKILL while the export wrote transforms.json (before meta.json, written last) left its temporary file; the
    cron job's rerun was refused as a folder holding other files ('pass --force', which would throw away the finished
    stages). The rerun sweeps it (the folder is the run's own: its marker, and held) and goes on; a user's file of
    another name still refuses."""
    from tests.test_capture_crashes import _exif_photos

    photos, out = _exif_photos(tmp_path / "p", 8, 65535), tmp_path / "cap"
    argv = ["recover-poses", "--images", str(photos), "--out", str(out), "--threads", "1"]
    assert main(argv) == 0
    (out / "meta.json").unlink()
    tmp = out / ".transforms.json.ab12cd34.json"
    tmp.write_text("{")
    capsys.readouterr()
    assert main(argv) == 0, capsys.readouterr().err
    assert not tmp.exists() and (out / "meta.json").is_file()
    (out / "meta.json").unlink()
    (out / ".transforms.json.mine").write_text("{")
    capsys.readouterr()
    assert main(argv) == 2 and ".transforms.json.mine" in error_line(capsys.readouterr().err)


@pytest.mark.slow
def test_make_shapenet_with_force_and_other_settings_while_a_run_renders_leaves_the_manifest(tmp_path, bpy_empty,
                                                                                            capsys):
    """make-shapenet checked and wrote the root manifest itself before its renders (prepare_output), outside the
    check render-dataset makes: its --force with another seed replaced the manifest of a dataset a live run was
    rendering into, and only its first render was refused, after its plan was recorded."""
    out = tmp_path / "sn"
    tiny = ["make-shapenet", "--views", "3", "--resolution", "8", "--engine", "BLENDER_WORKBENCH",
            "--objects-per-category", "1", "--out", str(out)]
    assert main(tiny + ["--shard", "0/13"]) == 0
    manifest = (out / F.ROOT_MANIFEST).read_text()
    plan = (out / "splits" / "plan.json").read_text()
    live = out / ".mrvm-run-l1v3l1v3"
    live.mkdir()
    settings = json.loads(manifest)["settings"]
    (live / "run.json").write_text(json.dumps({"pid": 4242, "host": "node7", "started": "now", "settings": settings}))
    with held(live):
        capsys.readouterr()
        code = main(tiny + ["--shard", "1/13", "--seed", "7", "--force"])
        line = error_line(capsys.readouterr().err)
    assert code == 2 and "being rendered by another run (pid 4242 on node7" in line, line
    assert (out / F.ROOT_MANIFEST).read_text() == manifest and (out / "splits" / "plan.json").read_text() == plan
