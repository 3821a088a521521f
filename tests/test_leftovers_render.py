"""What runs leave and meet: render-dataset holds each object folder while it renders it (a second run reaching it
is refused; shards of one folder go on side by side), sweeps what a killed run was writing there, and names its
dataset by an absolute path; synthesize --blend --force removes the images of the .blend it replaces that the new
one does not show."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from blender_mrvm.cli import main
from blender_mrvm.datasets import format as F
from tests.helpers import write_mesh
from tests.test_output_locks import error_line, held
from tests.test_synthesize import _args, setup  # noqa: F401  (the synthesis tests' references and tiny model)

pytestmark = pytest.mark.slow


def _argv(out, *sources, views=2, extra=()):
    return ["render-dataset", *(a for s in sources for a in ("--source", str(s))), "--views", str(views),
            "--resolution", "8", "--samples", "1", "--engine", "BLENDER_WORKBENCH", "--out", str(out), *extra]


def test_render_dataset_into_an_object_folder_another_run_holds_is_refused(tmp_path, bpy_empty, capsys):
    """Two runs rendering one object at once removed or mixed each other's views: the second is refused in one line.
    Shards of one folder hold different objects, so a shard runs while another holds its object."""
    meshes = [write_mesh(tmp_path / "m" / f"o{i}.ply") for i in range(3)]
    out = tmp_path / "d"
    assert main(_argv(out, meshes[2])) == 0  # the dataset exists (its root is checked before any object is held)
    with held(out / "custom" / "o0"):
        capsys.readouterr()
        code = main(_argv(out, tmp_path / "m", extra=("--shard", "0/2")))  # o0 and o2
        line = error_line(capsys.readouterr().err)
        assert code == 2 and "custom/o0 is in use by another process (pid 4242)" in line, line
        assert not (out / "custom" / "o0" / "meta.json").exists(), "nothing of it written"
        assert main(_argv(out, tmp_path / "m", extra=("--shard", "1/2"))) == 0  # the other shard renders meanwhile
    assert json.loads((out / "custom" / "o1" / "meta.json").read_text())["complete"]
    assert main(_argv(out, tmp_path / "m", extra=("--shard", "0/2"))) == 0
    assert not list(out.rglob(".lock")), "the lock goes with the run"
    assert sorted(F.read_split(out, "train") + F.read_split(out, "val") + F.read_split(out, "test")) == [
        "custom/o0", "custom/o1", "custom/o2"]


def test_a_killed_runs_temporaries_in_an_object_folder_are_swept_on_resume(tmp_path, bpy_empty):
    """SIGKILL mid-view leaves the views' and records' temporary files (``render._replace_into``, ``atomic_write``
    names: hidden, beside the files); the next run, holding the folder, removes them, and leaves other files."""
    mesh = write_mesh(tmp_path / "m.ply")
    out = tmp_path / "d"
    assert main(_argv(out, mesh, views=3)) == 0
    obj = out / "custom" / "m"
    for k in F.VIEW_DIRS:  # the last view was being written when the run was killed
        (obj / k / f"{F.view_name(2)}{F.VIEW_EXT[k]}").unlink()
    meta = json.loads((obj / "meta.json").read_text())
    (obj / "meta.json").write_text(json.dumps({**meta, "complete": False}))
    left = [obj / "rgb" / ".000002.png.99999.0.png", obj / "depth" / ".000002.exr.99999.1.exr",
            obj / "pose" / ".000002.txt.99999.4.txt", obj / ".meta.json.k2j4l9x_.json",
            obj / ".transforms.json.abc123.json"]
    for p in left:
        p.write_bytes(b"half")
    (obj / "notes.txt").write_text("the user's")
    (obj / "rgb" / ".DS_Store").write_text("the file browser's")
    assert main(_argv(out, mesh, views=3)) == 0
    assert not [p for p in left if p.exists()]
    assert (obj / "notes.txt").read_text() == "the user's" and (obj / "rgb" / ".DS_Store").is_file()
    assert json.loads((obj / "meta.json").read_text())["complete"]
    # a finished object's leftovers too (a run killed while it updated meta.json)
    (obj / ".meta.json.zz.json").write_text("{")
    assert main(_argv(out, mesh, views=3)) == 0
    assert not (obj / ".meta.json.zz.json").exists()


def test_render_dataset_summary_names_the_dataset_by_its_absolute_path(tmp_path, bpy_empty, capsys, monkeypatch):
    mesh = write_mesh(tmp_path / "m.ply")
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    assert main(_argv(Path("rel") / "d", mesh, views=1)) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert line.endswith(f"-> {(tmp_path / 'rel' / 'd').resolve()}"), line


def test_blend_force_removes_the_images_of_the_replaced_blend_that_the_new_one_does_not_show(setup, tmp_path,  # noqa: F811
                                                                                           addon):
    """``synthesize --blend X --force`` rewrote X_novel_views/ with the new planes' images and left the old planes'
    (other targets: other names) beside them. The old .blend's images there that the new one does not show go; files
    the old .blend did not show (a user's) stay."""
    import bpy

    root, obj, ck, tg = setup
    blend = tmp_path / "s.blend"
    images = tmp_path / "s_novel_views"
    try:
        assert main(_args(root, obj, ck, tmp_path / "o1", "--blend", str(blend))) == 0
        assert sorted(p.name for p in images.iterdir()) == [
            "view_002.png", "view_002_depth.exr", "view_003.png", "view_003_depth.exr", "wide.png", "wide_depth.exr"]
        (images / "mine.png").write_bytes(b"the user's")
        argv = [a for a in _args(root, obj, ck, tmp_path / "o2", "--blend", str(blend), "--force")]
        i = argv.index("--targets")
        argv[i:i + 2] = ["--orbit", "2"]
        assert main(argv) == 0
        assert sorted(p.name for p in images.iterdir()) == ["mine.png", "orbit_000.png", "orbit_001.png"]
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        shown = {Path(bpy.path.abspath(im.filepath)).name for im in bpy.data.images if im.filepath}
        assert {"orbit_000.png", "orbit_001.png"} <= shown
    finally:
        bpy.ops.wm.read_homefile(use_empty=True)
