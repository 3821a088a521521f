"""The CLI and every kind of bad input: one-line error, non-zero exit, nothing lost or marked done."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from blender_mrvm.cli import main
from tests.helpers import write_mesh

ROOT = Path(__file__).resolve().parents[1]


def run_cli(capsys, *args):
    code = main([str(a) for a in args])
    err = capsys.readouterr().err.strip()
    return code, err


def one_line_error(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, err
    return lines[0]


@pytest.fixture
def mesh(tmp_path):
    return write_mesh(tmp_path / "good.ply")


def base(out, src):
    return ["render-dataset", "--source", src, "--out", out, "--views", "2", "--resolution", "16", "--samples", "1"]


@pytest.mark.parametrize("extra,needle", [
    (["--views", "0"], "views must be at least 1"),
    (["--views", "-3"], "views must be at least 1"),
    (["--resolution", "0"], "at least 1x1"),
    (["--resolution", "8193"], "exceeds the maximum of 8192"),
    (["--resolution", "64x9000"], "exceeds the maximum"),
    (["--resolution", "big"], "resolution must be R or WxH"),
    (["--rig", "cube"], "unknown rig"),
    (["--engine", "povray"], "unknown engine"),
    (["--shard", "3/2"], "shard must be i/n"),
    (["--samples", "0"], "samples must be at least 1"),
    (["--fov", "180"], "field of view"),
])
def test_bad_arguments(capsys, tmp_path, mesh, extra, needle):
    code, err = run_cli(capsys, *base(tmp_path / "out", mesh), *extra)
    assert code != 0 and needle in one_line_error(err)
    assert not (tmp_path / "out").exists(), "nothing is written for bad arguments"


def test_missing_corrupt_unsupported_files(capsys, tmp_path, bpy_empty):
    code, err = run_cli(capsys, *base(tmp_path / "o1", tmp_path / "nope.obj"))
    assert code == 2 and "not found" in one_line_error(err)
    bad = tmp_path / "model.xyz"
    bad.write_text("1 2 3\n")
    code, err = run_cli(capsys, *base(tmp_path / "o2", bad))
    assert code == 2 and "unsupported mesh format '.xyz'" in one_line_error(err)
    for name, content in (("broken.obj", "v 0 0\nf 1 2 9\ngarbage\n"), ("broken.ply", "ply\nformat nonsense\n"),
                          ("broken.stl", "solid x\nnot really\n"), ("broken.off", "OFF\n3 1\n0 0\n"),
                          ("broken.glb", "glTF nonsense"), ("empty.obj", "")):
        f = tmp_path / name
        f.write_text(content)
        out = tmp_path / f"o_{name}"
        code, err = run_cli(capsys, *base(out, f))
        assert code == 2 and f"cannot read mesh file {f}" in one_line_error(err), (name, err)
        metas = list(out.rglob("meta.json"))
        assert all(not json.loads(m.read_text())["complete"] for m in metas)
    empty_dir = tmp_path / "emptydir"
    empty_dir.mkdir()
    code, err = run_cli(capsys, *base(tmp_path / "o3", empty_dir))
    assert code == 2 and "no mesh files" in one_line_error(err)


def test_empty_selection(capsys, tmp_path, bpy_empty):
    import bpy

    blend = tmp_path / "empty.blend"  # from a shell, selected objects are those of the --blend file
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    code, err = run_cli(capsys, *base(tmp_path / "o", "selected"), "--blend", str(blend))
    assert code == 2 and "no mesh, curve, surface, text or metaball objects are selected" in one_line_error(err)
    bpy.ops.wm.read_homefile(use_empty=True)


def test_scene_rig_without_cameras(capsys, tmp_path, bpy_empty):
    import bpy

    bpy.ops.mesh.primitive_cube_add()
    blend = tmp_path / "cube.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    code, err = run_cli(capsys, *base(tmp_path / "o", "selected"), "--rig", "scene", "--blend", str(blend))
    assert code == 2 and "needs cameras in the scene" in one_line_error(err)
    bpy.ops.wm.read_homefile(use_empty=True)


def test_output_not_writable(capsys, tmp_path, mesh, bpy_empty):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, err = run_cli(capsys, *base(blocker, mesh))
    assert code == 2 and "exists and is not a folder" in one_line_error(err)
    code, err = run_cli(capsys, *base(blocker / "sub", mesh))
    assert code == 2 and "is not writable" in one_line_error(err)
    code, err = run_cli(capsys, *base("/proc/mrvm_out", mesh))
    assert code == 2 and "is not writable" in one_line_error(err)


def test_no_silent_overwrite(capsys, tmp_path, mesh, bpy_empty):
    other = tmp_path / "other"
    other.mkdir()
    (other / "precious.txt").write_text("keep me")
    code, err = run_cli(capsys, *base(other, mesh))
    assert code == 2 and "not empty and holds no blender_mrvm dataset" in one_line_error(err)
    assert (other / "precious.txt").read_text() == "keep me" and len(list(other.iterdir())) == 1

    out = tmp_path / "ds"
    assert run_cli(capsys, *base(out, mesh))[0] == 0
    first = (out / "custom" / "good" / "rgb" / "000000.png").read_bytes()
    code, err = run_cli(capsys, *base(out, mesh), "--samples", "4")
    assert code == 2 and "rendered with other settings (samples 1 != 4)" in one_line_error(err)
    assert (out / "custom" / "good" / "rgb" / "000000.png").read_bytes() == first
    code, err = run_cli(capsys, *base(out, mesh), "--samples", "4", "--force")
    assert code == 0
    meta = json.loads((out / "custom" / "good" / "meta.json").read_text())
    assert meta["settings"]["samples"] == 4 and meta["complete"]


def test_contact_sheet_leaves_out_objects_it_cannot_show(capsys, tmp_path):
    """A dataset with an interrupted object (Ctrl-C: meta.json not complete, no camera files yet) and an object
    folder without views: the sheet shows the finished object and a note names the two left out (the first stopped
    it with an error, the second with a traceback)."""
    from blender_mrvm.datasets import format as F
    from blender_mrvm.training.synthetic import make_sphere_dataset

    ds = make_sphere_dataset(tmp_path / "ds", n_objects=3, n_views=3, resolution=16, seed=1)
    cut = ds / "spheres" / "obj000"
    cut.joinpath("meta.json").write_text(json.dumps({**json.loads((cut / "meta.json").read_text()), "complete": False}))
    for f in ("intrinsics.txt", "transforms.json"):
        (cut / f).unlink(missing_ok=True)
    for f in (ds / "spheres" / "obj001").glob("*/*.*"):
        f.unlink()
    code, err = run_cli(capsys, "contact-sheet", "--dataset", ds, "--out", tmp_path / "sheet.png", "--views", "2")
    assert code == 0, err
    assert "left out" in err and "spheres/obj000 (unfinished)" in err and "spheres/obj001 (no views)" in err, err
    assert F.read_png(tmp_path / "sheet.png").shape[0] == 16 + 96, "one row: the finished object"


def test_help_lists_commands(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for cmd in ("render-dataset", "build-extension", "bench", "demo"):
        assert cmd in out


def _parsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, path + (name,))


def test_every_commands_help_formats():
    """`--help` of every command and subcommand prints (argparse expands each help string with `%`: a bare `%`
    in one made `synthesize --help` raise TypeError, and nothing ran the help of every command)."""
    from blender_mrvm.cli import build_parser

    seen = []
    for path, parser in _parsers(build_parser()):
        text = parser.format_help()
        assert text.startswith("usage:"), path
        seen.append(" ".join(path))
    assert {"synthesize", "bench tradeoff", "sem2nerf render", "render-dataset"} <= set(seen), seen
    assert len(seen) >= 20, seen


@pytest.mark.slow
def test_blender_script_entry_point(tmp_path, mesh):
    """`blender --background -P scripts/mrvm_blender.py -- render-dataset ...`, imitated with the bpy module."""
    env = dict(os.environ, PYTHONPATH="")
    cmd = [sys.executable, str(ROOT / "scripts" / "mrvm_blender.py"), "--", *base(tmp_path / "out", mesh)]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert (tmp_path / "out" / "custom" / "good" / "pose" / "000001.txt").is_file()
    res = subprocess.run([sys.executable, str(ROOT / "scripts" / "mrvm_blender.py"), "--", *base(tmp_path / "o2", "nope.obj")],
                         capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300)
    assert res.returncode == 2 and "error: mesh file or folder not found: nope.obj" in res.stderr


def test_help_keeps_the_examples_one_a_line(capsys):
    """argparse's default formatter joined the commands' examples into one paragraph."""
    from blender_mrvm.cli import main

    with pytest.raises(SystemExit) as e:
        main(["train", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "\nData-parallel:   torchrun" in out and "\nFine-tune:" in out
    with pytest.raises(SystemExit):
        main(["bench", "--help"])
    assert "OpenMP policies and chunk workers." in " ".join(capsys.readouterr().out.split())  # its first line, whole


def test_help_states_defaults_and_engines_are_spelled_alike(capsys):
    """Options whose help did not state their default now show it; make-shapenet took CYCLES only in capitals and
    preview-library refused BLENDER_WORKBENCH, the spelling the other commands use."""
    from blender_mrvm.cli import build_parser

    with pytest.raises(SystemExit):
        build_parser().parse_args(["make-shapenet", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "samples per pixel (default: 8)" in out and "(default 2)" in out and "(default: 2)" not in out
    a = build_parser().parse_args(["make-shapenet", "--out", "x", "--engine", "cycles"])
    b = build_parser().parse_args(["preview-library", "--out", "x.png", "--engine", "BLENDER_WORKBENCH"])
    assert a.engine == "CYCLES" and b.engine == "WORKBENCH"


def test_orbit_options_without_orbit_and_a_missing_gpu_in_demo_are_refused_first(tmp_path, capsys):
    """synthesize took --orbit-elevation 95 with --target-views and ignored it; demo --device cuda without a GPU
    rendered the dataset before failing, leaving its files in --out."""
    import torch

    from blender_mrvm.cli import main

    assert main(["synthesize", "--references", str(tmp_path), "--target-views", "2", "--orbit-elevation", "95",
                 "--out", str(tmp_path / "o")]) == 2
    assert "--orbit-elevation: only for --orbit N" in capsys.readouterr().err and not (tmp_path / "o").exists()
    if not torch.cuda.is_available():
        assert main(["demo", "--device", "cuda", "--out", str(tmp_path / "d")]) == 2
        assert "no CUDA GPU" in capsys.readouterr().err and not (tmp_path / "d").exists()


def test_ctrl_c_while_a_library_loads_is_an_interrupt_not_a_broken_install(capsys, monkeypatch, tmp_path):
    """Ctrl-C in the first second of recover-poses landed in pycolmap's import, which re-raises it as 'RuntimeError:
    Cannot import the C++ backend ... Make sure that you successfully install the package' (exit 1, a traceback
    blaming the install): exit 130 and the CLI's one interrupt line. A library's own RuntimeError keeps its
    traceback."""
    from blender_mrvm.commands import recover_poses

    def interrupted_import(args):
        try:
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt as k:
                raise ImportError("initialization failed") from k
        except ImportError as e:
            raise RuntimeError("Cannot import the C++ backend pycolmap._core.") from e

    monkeypatch.setattr(recover_poses, "run", interrupted_import)
    assert main(["recover-poses", "--images", str(tmp_path), "--out", str(tmp_path / "o")]) == 130
    assert capsys.readouterr().err.strip().splitlines() == [f"error: interrupted; the stages finished so far are kept in {tmp_path / 'o' / 'colmap'}; the same "
                                                             "command goes on from them"]

    def broken(args):
        raise RuntimeError("a bug")

    monkeypatch.setattr(recover_poses, "run", broken)
    with pytest.raises(RuntimeError, match="a bug"):
        main(["recover-poses", "--images", str(tmp_path), "--out", str(tmp_path / "o")])
