"""scripts/gpu_session.sh's train mode carries a run across GPU sessions (docs/gpu_session.md): a call stopped by
its time limit returns the run resumable (<name>.run.tgz), and the next call, with that file in gpu_pack/runs/,
resumes it from its last checkpoint instead of starting over. Run here on the CPU with a tiny model."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest

from blender_mrvm.training.synthetic import make_sphere_dataset

REPO = Path(__file__).resolve().parents[1]


def _call(root: Path, out: Path, seconds: int, **extra: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "OUT": str(out), "PY": sys.executable, "OMP_NUM_THREADS": "1", **extra}
    return subprocess.run(["bash", "scripts/gpu_session.sh", "train", "tiny.json", str(seconds)], cwd=root, env=env,
                          capture_output=True, text=True, timeout=seconds + 120)


def _steps(tgz: Path) -> tuple[list[str], list[int], list[str]]:
    """metrics.jsonl's lines, their steps, and the archive's names."""
    with tarfile.open(tgz) as t:
        names = t.getnames()
        lines = [line for line in t.extractfile("metrics.jsonl").read().decode().splitlines() if line.strip()]
    return lines, [json.loads(line)["step"] for line in lines], names


@pytest.mark.slow
def test_a_run_stopped_by_its_limit_comes_back_resumable_and_resumes(tmp_path):
    root = tmp_path / "repo"
    (root / "scripts").mkdir(parents=True)
    shutil.copy(REPO / "scripts" / "gpu_session.sh", root / "scripts")
    (root / "blender_mrvm").symlink_to(REPO / "blender_mrvm")
    (root / "gpu_carry").mkdir()
    data = make_sphere_dataset(root / "data", n_objects=2, n_views=4, resolution=16, data_passes=False)
    cfg = {"model": {"kind": "nerformer_mrvm", "config": {"name": "fast"}},
           "train": {"data": str(data), "split": "train", "iterations": 1_000_000, "objects_per_step": 1,
                     "rays_per_object": 16, "ckpt_every": 1_000_000, "log_every": 1, "threads": 1, "device": "cpu",
                     "pretrain_frac": 0.0, "lpips_weight": 0.0, "opacity_weight": 0.0}}
    (root / "tiny.json").write_text(json.dumps(cfg))

    # a part size far under the tiny run's archive: it comes back in parts (an `accurate` run is ~26 MB packed and
    # a returned file may have 16 MiB), each within the size, and the next call joins them
    part = 40_000
    first = _call(root, tmp_path / "out1", 20, RUN_PART_BYTES=str(part))
    parts = sorted((tmp_path / "out1").glob("tiny.run.tgz.part*"))
    assert len(parts) >= 2 and not (tmp_path / "out1" / "tiny.run.tgz").exists(), first.stdout + first.stderr
    assert parts[0].name == "tiny.run.tgz.part00" and all(p.stat().st_size <= part for p in parts)
    tgz = tmp_path / "tiny.run.tgz"
    tgz.write_bytes(b"".join(p.read_bytes() for p in parts))
    assert (tmp_path / "out1" / "tiny.safetensors").is_file()
    lines1, steps1, names = _steps(tgz)
    ck = [n for n in names if n.startswith("checkpoints/step_") and n.count("/") == 1]
    assert len(ck) == 1 and {"config.json", f"{ck[0]}/model.safetensors", f"{ck[0]}/trainer_state.pt"} <= set(names)
    saved = int(ck[0].rsplit("_", 1)[1])
    # the limit's SIGINT let the step in progress finish and saved it: no step is lost to ckpt_every
    assert saved >= 2 and saved == steps1[-1]

    # the next session: a bare machine with the returned run in gpu_pack/runs/
    shutil.rmtree(root / "runs")
    (root / "gpu_pack" / "runs").mkdir(parents=True)
    for p in parts:
        shutil.copy(p, root / "gpu_pack" / "runs")
    second = _call(root, tmp_path / "out2", 20)
    assert f"resuming from step_{saved:07d}" in second.stdout, second.stdout + second.stderr
    lines2, steps2, names2 = _steps(tmp_path / "out2" / "tiny.run.tgz")
    # one unbroken history: the first call's lines up to its checkpoint, kept as they were (a run started over
    # would rewrite them with its own times), then the second call's from the step after it
    k = steps1.index(saved) + 1
    assert lines2[:k] == lines1[:k]
    assert all(b == a + 1 for a, b in zip(steps2, steps2[1:])) and steps2[-1] > saved
    assert int(next(n for n in names2 if n.count("/") == 1 and "step_" in n).rsplit("_", 1)[1]) >= saved


@pytest.mark.slow
def test_gpu_carry_keeps_k_objects_a_category_and_the_loader_takes_them(tmp_path):
    """scripts/gpu_carry.sh with PER_CATEGORY=K carries the first K objects of each category of the named splits (the
    lists run category by category: MAX_OBJECTS alone keeps the first categories) and cuts the carried split lists
    to them, so the training loader takes the carried set instead of refusing it as half-rendered."""
    from blender_mrvm.datasets.loaders import load_dataset

    root = tmp_path / "repo"
    (root / "scripts").mkdir(parents=True)
    for s in ("gpu_carry.sh", "carry_weights.py"):
        shutil.copy(REPO / "scripts" / s, root / "scripts")
    (root / "blender_mrvm").symlink_to(REPO / "blender_mrvm")
    (root / ".git").mkdir()
    data = tmp_path / "data" / "set"
    for i, cat in enumerate(("a", "b")):
        make_sphere_dataset(data, n_objects=4, n_views=3, resolution=8, category=cat, seed=i, data_passes=False)
    (data / "splits" / "train.lst").write_text("".join(f"{c}/obj00{j}\n" for c in "ab" for j in range(3)))
    (data / "splits" / "test.lst").write_text("a/obj003\nb/obj003\n")
    with pytest.raises(Exception, match="half-rendered"):  # what the loader said before the lists were cut
        _refused(data)
    env = {**os.environ, "SPLITS": "train", "PER_CATEGORY": "2", "PY": sys.executable}
    run = subprocess.run(["bash", "scripts/gpu_carry.sh", str(data)], cwd=root, env=env, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    carried = root / "gpu_carry" / "data" / "set"
    kept = ["a/obj000", "a/obj001", "b/obj000", "b/obj001"]
    assert (carried / "splits" / "train.lst").read_text().split() == kept
    assert sorted(p.relative_to(carried).as_posix() for p in carried.glob("*/obj*")) == kept
    assert len(load_dataset(carried, "train")) == 4
    assert (root / "gpu_pack" / "carry.tgz").is_file()
    assert "/gpu_carry/" in (root / ".git" / "info" / "exclude").read_text()


def _refused(data: Path) -> None:
    """The loader on a copy of ``data`` with one listed object removed (a carry that kept the whole lists)."""
    from blender_mrvm.datasets.loaders import load_dataset

    part = data.parent / "part"
    shutil.copytree(data, part)
    shutil.rmtree(part / "b" / "obj002")
    load_dataset(part, "train")


@pytest.mark.slow
@pytest.mark.parametrize("recipe", ["", "official"])
def test_mrvm_scale_trains_both_arms_with_the_two_run_recipe(tmp_path, recipe):
    """`gpu_session.sh mrvm_scale` (issue 11's MRVM trend at a GPU budget), here on the CPU with a tiny batch: each
    arm pretrains PRE steps (the MRVM arm masking) and finetunes PRE/3 from it (no masking, lr 1e-4), or with
    FT_RECIPE=official 2 x PRE steps at a constant lr 1e-3 (the official code's finetune); the arms differ only in
    MRVM, and the fp16 models, logs and run configs come back with the steps each run reached."""
    root = tmp_path / "repo"
    (root / "scripts").mkdir(parents=True)
    shutil.copy(REPO / "scripts" / "gpu_session.sh", root / "scripts")
    (root / "blender_mrvm").symlink_to(REPO / "blender_mrvm")
    data = make_sphere_dataset(tmp_path / "data", n_objects=2, n_views=4, resolution=16, data_passes=False)
    out = tmp_path / "out"
    out.mkdir()
    env = {**os.environ, "OUT": str(out), "PY": sys.executable, "OMP_NUM_THREADS": "1", "DEVICE": "cpu", "OBJ": "1",
           "RAYS": "16", "PRE": "3", "MRVM_DATA": str(data), "FT_RECIPE": recipe}
    r = subprocess.run(["bash", "scripts/gpu_session.sh", "mrvm_scale"], cwd=root, env=env, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    ft = 6 if recipe else 1
    for run, want in (("scale_mrvm_pre", 3), ("scale_mrvm", ft), ("scale_base_pre", 3), ("scale_base", ft)):
        assert f"runs/{run}: step {want} of {want}\n" in r.stdout, r.stdout + r.stderr
    assert "CUT SHORT" not in r.stdout
    assert {p.name for p in out.iterdir()} >= {"scale_mrvm.safetensors", "scale_base.safetensors", "scale_mrvm.log",
                                               "scale_base.log", "scale_runs.tgz"}
    with tarfile.open(out / "scale_runs.tgz") as t:
        cfg = {n.split("/")[0]: json.load(t.extractfile(n)) for n in t.getnames() if n.endswith("config.json")}
        masking = {n.split("/")[0]: {json.loads(x)["masking"] for x in t.extractfile(n).read().decode().splitlines()}
                   for n in t.getnames() if n.endswith("metrics.jsonl")}
    assert [cfg[r]["model"]["config"]["mrvm"]["enabled"] for r in ("scale_mrvm_pre", "scale_base_pre")] == [True, False]
    assert masking == {"scale_mrvm_pre": {True}, "scale_mrvm": {False}, "scale_base_pre": {False}, "scale_base": {False}}
    if recipe:  # the official finetune: constant 1e-3, no warm-up
        assert [cfg["scale_mrvm"]["train"][k] for k in ("lr", "lr_final_frac", "lr_warmup")] == [1e-3, 1.0, 0]
    else:
        assert cfg["scale_mrvm"]["train"]["lr"] == cfg["scale_base"]["train"]["lr"] == 1e-4  # the finetuning policy
    strip = lambda c: {**c["train"], "out_dir": "", "init_checkpoint": ""}  # noqa: E731
    assert strip(cfg["scale_mrvm"]) == strip(cfg["scale_base"]) and strip(cfg["scale_mrvm_pre"]) == strip(cfg["scale_base_pre"])
    assert cfg["scale_mrvm_pre"]["train"]["objects_per_step"] == 1 and cfg["scale_mrvm_pre"]["train"]["rays_per_object"] == 16
    # the pretraining warmup in proportion to the run (PRE / 5, at most the default 200): session 28's first GPU
    # runs kept 200 steps of warmup in a 180-step run, so their learning rate never peaked
    assert cfg["scale_mrvm_pre"]["train"]["lr_warmup"] == cfg["scale_base_pre"]["train"]["lr_warmup"] == 1


@pytest.mark.slow
def test_synth_variants_time_the_shipped_model_and_nofoot_changes_no_pixel(tmp_path):
    """`gpu_session.sh synth` (issue 13's `synthesize` timings), here on the CPU at 32 px: each variant's timing
    comes back, and `nofoot` (empty-space skipping with every box ray marched, the footprint left out) renders
    the same pixels as the default: the footprint only saves marching, never changes a kept ray."""
    root = tmp_path / "repo"
    (root / "scripts").mkdir(parents=True)
    shutil.copy(REPO / "scripts" / "gpu_session.sh", root / "scripts")
    (root / "blender_mrvm").symlink_to(REPO / "blender_mrvm")
    data = make_sphere_dataset(tmp_path / "data", n_objects=1, n_views=4, resolution=64, data_passes=False)
    out, tmp = tmp_path / "out", tmp_path / "tmp"
    out.mkdir()
    env = {**os.environ, "OUT": str(out), "PY": sys.executable, "OMP_NUM_THREADS": "1", "DEVICE": "cpu",
           "SYNTH_DATA": str(data), "SYNTH_TMP": str(tmp), "SYNTH_VIEWS": "0 2", "ORBIT": "3", "SIZE": "32",
           "SYNTH_MODELS": "nerformer_mrvm", "SYNTH_VARIANTS": "eager nofoot noskip"}
    r = subprocess.run(["bash", "scripts/gpu_session.sh", "synth"], cwd=root, env=env, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    for c in ("eager", "nofoot", "noskip"):
        assert f"nerformer_mrvm_{c}: 3 views of 32 px" in r.stdout, r.stdout + r.stderr
        assert json.loads((out / f"nerformer_mrvm_{c}.json").read_text())["device"] == "cpu"
    import numpy as np
    from PIL import Image

    logs = {c: (tmp / "synth_logs" / f"nerformer_mrvm_{c}.log").read_text() for c in ("eager", "nofoot")}
    assert logs["nofoot"].count("nofoot: every pixel of a 32x32 view marched") == 3 and "nofoot" not in logs["eager"]
    pngs = sorted((tmp / "synth_nerformer_mrvm_eager").rglob("*.png"))
    assert len(pngs) >= 3
    for a in pngs:
        b = tmp / "synth_nerformer_mrvm_nofoot" / a.relative_to(tmp / "synth_nerformer_mrvm_eager")
        assert np.array_equal(np.asarray(Image.open(a)), np.asarray(Image.open(b))), a.name
    ev = json.loads((out / "nerformer_mrvm_eager.json").read_text())
    nf = json.loads((out / "nerformer_mrvm_nofoot.json").read_text())
    assert [t["evaluated_rays"] for t in ev["targets"]] == [t["evaluated_rays"] for t in nf["targets"]]  # same rays


@pytest.mark.slow
def test_score_evaluates_carried_models_on_the_packed_sets(tmp_path):
    """`gpu_eval_pack.sh` carries the first K objects of a category of each named split (without depth) with the
    LPIPS weights in fp16 and the models named, and `gpu_session.sh score` evaluates every checkpoint on every set
    (here on the CPU): the shipped model and a carried copy of its file score the same views identically, LPIPS
    included, so the pairing done afterwards compares like with like."""
    root = tmp_path / "repo"
    (root / "scripts").mkdir(parents=True)
    for s in ("gpu_session.sh", "gpu_eval_pack.sh", "carry_weights.py"):
        shutil.copy(REPO / "scripts" / s, root / "scripts")
    (root / "blender_mrvm").symlink_to(REPO / "blender_mrvm")
    (root / ".git" / "info").mkdir(parents=True)
    data = tmp_path / "data" / "set"
    for i, cat in enumerate(("a", "b")):
        make_sphere_dataset(data, n_objects=3, n_views=4, resolution=16, category=cat, seed=i, data_passes=False)
    (data / "splits" / "test.lst").write_text("".join(f"{c}/obj00{j}\n" for c in "ab" for j in range(3)))
    (data / "splits" / "eval_views.json").write_text(json.dumps({"input_views_2": [0, 1]}))
    model = REPO / "blender_mrvm" / "assets" / "checkpoints" / "mrvm_shapenet13_all.safetensors"
    env = {**os.environ, "PY": sys.executable, "OMP_NUM_THREADS": "1"}
    pack = subprocess.run(["bash", "scripts/gpu_eval_pack.sh", f"{data}:test:2", "--", str(model)], cwd=root,
                          env=env, capture_output=True, text=True, timeout=300)
    assert pack.returncode == 0, pack.stdout + pack.stderr
    assert "/gpu_eval/" in (root / ".git" / "info" / "exclude").read_text()
    with tarfile.open(root / "gpu_eval" / "eval.tgz") as t:
        names = t.getnames()
        assert t.extractfile("data/set/splits/test.lst").read().decode().split() == \
            ["a/obj000", "a/obj001", "b/obj000", "b/obj001"]
    assert not any("obj002" in n or "/depth" in n for n in names)
    assert "weights/vgg16_imagenet_features.safetensors" in names and "models/mrvm_shapenet13_all.safetensors" in names
    out = tmp_path / "out"
    out.mkdir()
    env = {**env, "OUT": str(out), "DEVICE": "cpu", "SCORE_SETS": "set:test:2", "SCORE_JOBS": "2", "SCORE_S": "240",
           "SCORE_TMP": str(tmp_path / "score")}
    r = subprocess.run(["bash", "scripts/gpu_session.sh", "score", "shipped",
                        "gpu_eval/models/mrvm_shapenet13_all.safetensors"], cwd=root, env=env, capture_output=True,
                       text=True, timeout=400)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "shipped__set_test: rc 0" in r.stdout and "mrvm_shapenet13_all__set_test: rc 0" in r.stdout, r.stdout
    with tarfile.open(out / "score.tgz") as t:
        a, b = (json.load(t.extractfile(f"./{n}__set_test/eval.json")) for n in ("shipped", "mrvm_shapenet13_all"))
    key = lambda v: (v["object"], v["view"])  # noqa: E731
    assert sorted(map(key, a["views"])) == sorted(map(key, b["views"])) and len(a["views"]) == 4 * 2
    assert a["overall"]["psnr"] == pytest.approx(b["overall"]["psnr"], abs=1e-6)
    assert a["overall"]["lpips"] == pytest.approx(b["overall"]["lpips"], abs=1e-6) and a["overall"]["lpips"] > 0
    table = subprocess.run([sys.executable, str(REPO / "scripts" / "score_table.py"), str(out / "score.tgz"), "shipped"],
                           capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert table.returncode == 0, table.stderr
    row = next(line for line in table.stdout.splitlines() if "| mrvm_shapenet13_all |" in line)
    assert "| set_test | mrvm_shapenet13_all | 8 |" in row and "+0.000 (0.000), 0 of 4" in row, table.stdout


def test_score_table_pools_sets_into_one_paired_row(tmp_path):
    """`score_table.py --pool NAME=A,B` reads two sets as one (a rule's "both halves pooled"): the paired
    difference is the mean over all their objects with the SE over all of them, objects of one name in two sets
    stay two objects; an unknown set in a pool is a one-line error."""
    import io

    def ev(objs, psnr):  # one eval.json: objects x 2 views, PSNR by object
        views = [{"category": "c", "object": o, "view": v, "psnr": psnr[o] + v * 0.1, "ssim": 0.5, "lpips": 0.2}
                 for o in objs for v in range(2)]
        return {"views": views, "overall": {"n": len(views), "psnr": float(np.mean([x["psnr"] for x in views])),
                                            "ssim": 0.5, "lpips": 0.2}}

    base_a, base_b = ev(["o1", "o2"], {"o1": 20, "o2": 21}), ev(["o1", "o3"], {"o1": 18, "o3": 19})
    cand_a, cand_b = ev(["o1", "o2"], {"o1": 21, "o2": 21}), ev(["o1", "o3"], {"o1": 18, "o3": 22})
    tgz = tmp_path / "score.tgz"
    with tarfile.open(tgz, "w:gz") as t:
        for name, rep in (("base__a", base_a), ("base__b", base_b), ("cand__a", cand_a), ("cand__b", cand_b)):
            data = json.dumps(rep).encode()
            info = tarfile.TarInfo(f"./{name}/eval.json")
            info.size = len(data)
            t.addfile(info, io.BytesIO(data))
    run = lambda *a: subprocess.run([sys.executable, str(REPO / "scripts" / "score_table.py"), str(tgz), *a],  # noqa: E731
                                    capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(REPO)})
    r = run("base", "cand", "--pool", "ab=a,b")
    assert r.returncode == 0, r.stderr
    row = next(line for line in r.stdout.splitlines() if line.startswith("| ab | cand |"))
    d = np.array([1.0, 0.0, 0.0, 3.0])  # o1 in a, o2, o1 in b, o3: four objects
    assert "| 8 |" in row and f"{d.mean():+.3f} ({d.std(ddof=1) / 2:.3f}), 2 of 4" in row, row
    bad = run("base", "--pool", "ab=a,zz")
    assert bad.returncode == 2 and "no set 'zz'" in bad.stderr


@pytest.mark.slow
def test_objbatch_call_writes_a_row_per_configuration(tmp_path):
    """The `objbatch` call (the first of the next GPU session) runs on the CPU with its device named: per preset a CSV
    whose rows cross object_batch with ref_views_per, under the LPIPS patch loss."""
    import csv

    from blender_mrvm.models.vgg import weights_dir

    data = make_sphere_dataset(tmp_path / "data", n_objects=3, n_views=5, resolution=16, data_passes=False)
    env = {**os.environ, "OUT": str(tmp_path / "out"), "PY": sys.executable, "OMP_NUM_THREADS": "1",
           "MRVM_WEIGHTS_DIR": str(weights_dir()), "BENCH_DEVICE": "cpu", "OBJBATCH_RUNS": "fast:4x256",
           "BENCH_DATA": str(data), "STEPS": "1", "PRECISIONS": "fp32", "OBJECT_BATCHES": "1,4"}
    r = subprocess.run(["bash", "scripts/gpu_session.sh", "objbatch"], cwd=REPO, env=env, capture_output=True,
                       text=True, timeout=600)
    rows = list(csv.DictReader(open(tmp_path / "out" / "objbatch_fast" / "bench_train.csv")))
    assert [(x["object_batch"], x["ref_views_per"]) for x in rows] == [
        ("1", "object"), ("1", "step"), ("4", "object"), ("4", "step")], r.stdout + r.stderr
    assert all(float(x["steps_per_s"]) > 0 and x["lpips_weight"] == "0.5" for x in rows)
    check = (tmp_path / "out" / "objbatch_check.txt").read_text()  # the batched path checked first, on the device
    assert [line.split()[0] for line in check.splitlines() if "relative differences" in line] == [
        "nerformer", "legacy", "gpnr"] and "OVER" not in check, check


@pytest.mark.slow
@pytest.mark.parametrize("check_passes", [True, False])
def test_slice_checks_times_then_trains_the_batched_config_or_its_fallback(tmp_path, check_passes):
    """`gpu_session.sh slice CONFIG FALLBACK BUDGET` (the next GPU session's training call, session 34) on the CPU:
    the batched path is checked first; if right, timed at CONFIG's object_batch against one pass an object and CONFIG
    trained; if the check fails, FALLBACK trains instead and nothing is timed. Either way the run comes back."""
    import csv

    from blender_mrvm.models.vgg import weights_dir

    root = tmp_path / "repo"
    (root / "scripts").mkdir(parents=True)
    shutil.copy(REPO / "scripts" / "gpu_session.sh", root / "scripts")
    if check_passes:
        shutil.copy(REPO / "scripts" / "check_object_batch.py", root / "scripts")
    else:  # a device on which the batched losses or gradients are off: the check exits 1
        (root / "scripts" / "check_object_batch.py").write_text("import sys\nprint('nerformer OVER')\nsys.exit(1)\n")
    (root / "blender_mrvm").symlink_to(REPO / "blender_mrvm")
    if not check_passes:  # the tree before the batched loss came along (gpu_old/): the fallback trains with it
        shutil.copytree(REPO / "blender_mrvm", root / "gpu_old" / "blender_mrvm",
                        ignore=shutil.ignore_patterns("*.safetensors", "__pycache__"))
        main = root / "gpu_old" / "blender_mrvm" / "__main__.py"
        main.write_text("import sys\nprint('GPU_OLD_CODE', file=sys.stderr)\n" + main.read_text())
    data = make_sphere_dataset(tmp_path / "data", n_objects=3, n_views=5, resolution=16, data_passes=False)
    train = {"data": str(data), "split": "train", "iterations": 1_000_000, "objects_per_step": 2,
             "rays_per_object": 16, "ckpt_every": 1_000_000, "log_every": 1, "threads": 1, "device": "cpu",
             "pretrain_frac": 0.0, "lpips_weight": 0.0, "opacity_weight": 0.0}
    for name, extra in (("batched", {"object_batch": 2}), ("single", {})):
        (root / f"{name}.json").write_text(json.dumps({"model": {"kind": "nerformer_mrvm", "config": {"name": "fast"}},
                                                       "train": {**train, **extra}}))
    out = tmp_path / "out"
    # 20 s of training: with 8, the run once stopped before its first step (torch's start-up, under the whole suite)
    env = {**os.environ, "OUT": str(out), "PY": sys.executable, "OMP_NUM_THREADS": "1",
           "MRVM_WEIGHTS_DIR": str(weights_dir()), "BENCH_DEVICE": "cpu", "SLICE_BENCH_RUNS": "fast:2x256",
           "SLICE_BENCH_STEPS": "1", "BENCH_DATA": str(data), "PRECISIONS": "fp32", "SLICE_MIN_S": "20"}
    r = subprocess.run(["bash", "scripts/gpu_session.sh", "slice", "batched.json", "single.json", "1"], cwd=root,
                       env=env, capture_output=True, text=True, timeout=900)
    log = r.stdout + r.stderr
    assert r.returncode == 0, log
    check = (out / "objbatch_check.txt").read_text()
    use = "batched" if check_passes else "single"
    old = "" if check_passes else " with the code in gpu_old/"
    assert f"slice: training {use}.json{old} for 20 s (check {'passed' if check_passes else 'FAILED'})" in check, log
    assert ("GPU_OLD_CODE" in (out / f"{use}.log").read_text()) == (not check_passes)
    assert (out / f"{use}.safetensors").is_file() and not (out / f"{'single' if check_passes else 'batched'}.safetensors").exists()
    _, steps, _ = _steps(out / f"{use}.run.tgz")
    assert steps and steps[-1] >= 1
    bench = out / "objbatch_fast" / "bench_train.csv"
    if check_passes:
        rows = list(csv.DictReader(open(bench)))
        assert [(x["object_batch"], x["ref_views_per"]) for x in rows] == [
            ("1", "object"), ("1", "step"), ("2", "object"), ("2", "step")], log
        assert "relative differences" in check  # the real check's report, written once
        assert len(list(out.rglob("*"))) - 1 <= 8  # at most 8 files come back (the bench's folder is not one)
    else:
        assert not bench.exists()
    usage = subprocess.run(["bash", "scripts/gpu_session.sh", "slice", "batched.json"], cwd=root, env=env,
                           capture_output=True, text=True, timeout=60)
    assert usage.returncode == 2 and "usage:" in usage.stderr


@pytest.mark.slow
def test_slice_gives_the_rest_of_its_budget_to_the_fallback_when_the_batched_run_saves_nothing(tmp_path):
    """A batched slice that fails at once (on the device: out of memory at its first step) saved no step: `slice`
    trains the fallback for what is left of the budget instead of returning with the device time unused."""
    root = tmp_path / "repo"
    (root / "scripts").mkdir(parents=True)
    shutil.copy(REPO / "scripts" / "gpu_session.sh", root / "scripts")
    (root / "scripts" / "check_object_batch.py").write_text("print('nerformer relative differences ok')\n")
    (root / "blender_mrvm").symlink_to(REPO / "blender_mrvm")
    data = make_sphere_dataset(tmp_path / "data", n_objects=3, n_views=5, resolution=16, data_passes=False)
    train = {"data": str(data), "split": "train", "iterations": 1_000_000, "objects_per_step": 2,
             "rays_per_object": 16, "ckpt_every": 1_000_000, "log_every": 1, "threads": 1, "device": "cpu",
             "pretrain_frac": 0.0, "lpips_weight": 0.0, "opacity_weight": 0.0}
    model = {"kind": "nerformer_mrvm", "config": {"name": "fast"}}
    (root / "batched.json").write_text(json.dumps({"model": model, "train": {**train, "object_batch": 2,
                                                                              "data": str(tmp_path / "gone")}}))
    (root / "single.json").write_text(json.dumps({"model": model, "train": train}))
    out = tmp_path / "out"
    env = {**os.environ, "OUT": str(out), "PY": sys.executable, "OMP_NUM_THREADS": "1", "BENCH_DEVICE": "cpu",
           "SLICE_BENCH_RUNS": "fast:2x16", "SLICE_BENCH_STEPS": "1", "BENCH_DATA": str(data), "PRECISIONS": "fp32",
           "LPIPS_WEIGHT": "0", "SLICE_MIN_S": "8"}
    r = subprocess.run(["bash", "scripts/gpu_session.sh", "slice", "batched.json", "single.json", "50"], cwd=root,
                       env=env, capture_output=True, text=True, timeout=900)
    log = r.stdout + r.stderr
    check = (out / "objbatch_check.txt").read_text()
    assert "slice: training batched.json for" in check and "(batched.json saved no step: batched.log)" in check, log
    assert (out / "single.safetensors").is_file() and not (out / "batched.safetensors").exists(), log
    _, steps, _ = _steps(out / "single.run.tgz")
    assert steps and steps[-1] >= 1
