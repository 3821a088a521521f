"""The measuring tools behind the trade-off figures: Pareto fronts, the plot, peak memory, the stage
profile, the sweep's points, and the OpenMP policy the CLI and the worker set. bpy-free, fast."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from blender_mrvm import threads
from blender_mrvm.bench import PeakMemory
from blender_mrvm.bench import profile as prof
from blender_mrvm.bench import tradeoff as tr
from blender_mrvm.errors import InputError
from blender_mrvm.models import registry

ROOT = Path(__file__).resolve().parents[1]


def test_pareto_keeps_exactly_the_undominated_points():
    rows = [{"s": 1.0, "l": 0.30, "n": "a"}, {"s": 2.0, "l": 0.20, "n": "b"}, {"s": 3.0, "l": 0.25, "n": "c"},
            {"s": 0.5, "l": 0.40, "n": "d"}, {"s": 4.0, "l": 0.10, "n": "e"}, {"s": 2.5, "l": "", "n": "f"}]
    assert [r["n"] for r in tr.pareto(rows, "s", "l")] == ["d", "a", "b", "e"]


def test_plot_draws_both_panels(tmp_path):
    from PIL import Image

    rows = [{"kind": k, "point": p, "cpu_seconds_per_view": s, "psnr": q, "lpips": l, "quality": "measured", "size": 128}
            for k, p, s, q, l in [("a", "x", 0.5, 20.0, 0.3), ("a", "y", 1.0, 21.0, 0.25), ("b", "z", 2.0, 22.0, 0.2),
                                  ("b", "w", 3.0, 21.5, 0.22)]]
    path = tmp_path / "p.png"
    tr.plot(rows, path)
    img = np.asarray(Image.open(path).convert("RGB"))
    assert img.shape == (460, 1100, 3)
    for col in tr.COLOURS[:2]:  # each kind's points are drawn in both panels
        hit = np.all(img == col, axis=-1)
        assert hit[:, :550].any() and hit[:, 550:].any()


def test_front_names_the_model_of_each_point(tmp_path):
    """Several trained models of one kind share a front (e.g. `fast` and `balanced` at one budget): every
    front row names its preset and checkpoint, so two models' "as trained" points are told apart."""
    rows = [{"kind": "nerformer_mrvm", "checkpoint": f"runs/{c}", "preset": c, "point": "as trained",
             "cpu_seconds_per_view": s, "psnr": q, "ssim": 0.6, "lpips": l, "quality": "measured", "size": 128}
            for c, s, q, l in [("fast", 0.8, 15.2, 0.40), ("balanced", 2.0, 15.3, 0.35)]]
    tr.write_front(rows, tmp_path, 1.0)
    text = (tmp_path / "bench_tradeoff_front.md").read_text()
    assert "| fast (fast) | as trained | 0.800 |" in text and "| balanced (balanced) | as trained | 2.000 |" in text
    assert tr.point_name(rows[0], rows) == "fast (fast): as trained"
    assert tr.point_name(rows[0], rows[:1]) == "as trained"


def test_axes_always_measure_the_model_as_trained():
    """`bench tradeoff --axes precision` also measures the base point (fp32, as trained), so a sweep of one knob
    comes back with what to read it against; unknown knobs are a one-line error."""
    assert tr.parse_axes("precision") == ["base", "precision"]
    assert tr.parse_axes("samples, base,gate") == ["base", "samples", "gate"]
    assert tr.parse_axes(",".join(tr.AXES)) == list(tr.AXES)
    with pytest.raises(InputError, match="unknown knob"):
        tr.parse_axes("precision,fp8")


def test_sweep_moves_one_knob_at_a_time():
    cfg = registry.build_config(None, "balanced")
    pts = tr.sweep("nerformer_mrvm", cfg, list(tr.AXES), "cpu")
    base = tr.Point("base", "")
    for p in pts[1:]:
        moved = [f for f in ("overrides", "refs", "nearest", "ref_size", "precision", "skip", "chunk")
                 if getattr(p, f) != getattr(base, f)]
        assert len(moved) == 1, (p.label, moved)
    assert [p.precision for p in pts if p.axis == "precision"] == ["bf16", "int8"]  # fp16 only on a GPU, int8 on a CPU
    gpu = tr.sweep("nerformer_mrvm", cfg, ["precision"], "cuda")
    assert [p.precision for p in gpu if p.axis == "precision"] == ["bf16", "fp16"]
    gates = [p.overrides["render"]["fine_min_acc"] for p in pts if p.axis == "gate"]
    g = cfg.render.fine_min_acc
    assert sorted(gates) == [0.0, g / 10, 10 * g]  # off, a tenth of the default and 10x it
    stops = [p.overrides["render"]["stop_transmittance"] for p in pts if p.axis == "stop"]
    assert sorted(stops) == [1e-3, 1e-2, 0.1]  # the model's own (off) is the base point
    g = tr.sweep("gpnr", registry.build_config("gpnr", "fast"), ["samples"], "cuda")
    assert {p.overrides["n_samples"] for p in g} == {12, 48}
    assert not any(p.axis == "filter" for p in pts)  # a GPNR setting
    assert not tr.sweep("gpnr", registry.build_config("gpnr", "fast"), ["stop"], "cpu")  # a NeRFormer setting
    for own, other in (("bicubic", "bilinear"), ("bilinear", "bicubic")):  # the other read than the model's
        g = tr.sweep("gpnr", registry.build_config("gpnr", "fast", {"colour_filter": own}), ["filter"], "cpu")
        assert [p.overrides for p in g] == [{"colour_filter": other}]
    assert tr.ref_views(24, 2) == [3, 15] and len(set(tr.ref_views(24, 5))) == 5
    assert [p.nearest for p in pts if p.axis == "nearest"] == [2, 3, 5, 10]  # up to the model's most
    small = registry.build_config("gpnr", "fast", {"max_ref_views": 4})
    assert [p.nearest for p in tr.sweep("gpnr", small, ["nearest"], "cpu")] == [2, 3]


def test_peak_memory_sees_an_allocation():
    with PeakMemory("cpu") as pm:
        x = np.ones(64 * 2 ** 20 // 8)  # 64 MiB, touched
        x += 1
    del x
    assert 48 <= pm.mib <= 200


def test_profile_stages_add_up_and_restore_the_model():
    torch.manual_seed(0)
    model = registry.build_model(registry.build_config(None, "fast")).eval()
    from blender_mrvm.geometry import cameras

    intr = cameras.Intrinsics(30, 30, 12, 12, 24, 24)
    poses = [cameras.look_at_opencv(np.array(e, float)) for e in ([1.3, 0, 0.3], [0, 1.3, 0.3])]
    refs = np.random.default_rng(0).random((2, 24, 24, 3)).astype(np.float32)
    box = (np.full(3, -0.4), np.full(3, 0.4))

    def render():
        return model.synthesize(refs, poses, [intr] * 2, box, poses[0], intr)

    before = render()["color"]
    st = prof.profile_view(model, render)
    total = st.pop("total")
    assert {"encoder (network)", "gathering", "projection", "compositing", "sampling", "other"} <= set(st)
    assert sum(st.values()) == pytest.approx(total, rel=1e-6)
    import blender_mrvm.models.model as M

    assert M.sample_maps.__name__ == "sample_maps"  # the timers are gone
    assert torch.equal(render()["color"], before)


def test_omp_policy_is_set_unless_the_user_chose(monkeypatch):
    env = {}
    assert threads.apply_omp_defaults(env)["OMP_WAIT_POLICY"] == "PASSIVE"
    assert threads.apply_omp_defaults({"OMP_WAIT_POLICY": "ACTIVE"})["OMP_WAIT_POLICY"] == "ACTIVE"
    assert "OMP_WAIT_POLICY" not in threads.apply_omp_defaults({threads.KEEP_ENV: "1"})
    from blender_mrvm import worker

    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    monkeypatch.delenv(threads.KEEP_ENV, raising=False)
    assert worker.worker_env()["OMP_WAIT_POLICY"] == "PASSIVE"


FAULTS = """
import json, os, resource, sys
import json
from pathlib import Path

import numpy as np
from blender_mrvm import threads
from blender_mrvm.errors import InputError
policy = threads.apply_malloc_defaults()
def chunk():  # a chunk's forward pass: several blocks of a few MiB alive at once, then all freed
    live = [np.ones(n << 18, np.float32) for n in (8, 4, 8, 2, 8, 4)]
    del live
chunk()
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    chunk()
print(json.dumps({"policy": policy, "faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0}))
"""


@pytest.mark.skipif(__import__("platform").libc_ver()[0] != "glibc", reason="glibc's mallopt")
def test_malloc_thresholds_stop_chunk_sized_blocks_page_faulting_in_again():
    """Freed blocks of a few MiB are reused, not given back to the kernel and faulted in again page by page."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    def run(**extra):
        env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != threads.KEEP_MALLOC_ENV}
        out = subprocess.run([sys.executable, "-c", FAULTS], env={**env, **extra}, capture_output=True, text=True,
                             check=True, cwd=str(Path(threads.__file__).parents[1]))
        return json.loads(out.stdout)

    tuned, kept = run(), run(**{threads.KEEP_MALLOC_ENV: "1"})
    assert tuned["policy"] == "tuned" and kept["policy"] == "glibc defaults"
    assert kept["faults"] > 20 * 1000  # every block faulted in page by page
    assert tuned["faults"] < 200
    assert run(MALLOC_MMAP_THRESHOLD_="65536")["policy"] == "user's MALLOC_* environment"


def test_auto_thread_count_leaves_a_core():
    assert [threads.auto_threads(c) for c in (1, 2, 3, 16)] == [1, 1, 2, 15]
    n = threads.set_torch_threads(0)
    assert torch.get_num_threads() == n == threads.auto_threads()
    assert threads.set_torch_threads(1) == 1 and torch.get_num_threads() == 1


def test_bench_train_times_the_real_trainer(tmp_path, capsys):
    """`bench train`: one row per preset x batch x precision through the trainer's own loop, rays/s = steps/s x
    the batch's rays; a bad batch is one error before anything is written."""
    import csv

    from blender_mrvm.bench import train as bt
    from blender_mrvm.cli import main

    assert bt.parse_batches("2x256, 8X1024") == [(2, 256), (8, 1024)]
    for bad in ("2x", "x8", "2*256", "0x16", ""):
        with pytest.raises(Exception, match="--batches"):
            bt.parse_batches(bad)
    with pytest.raises(Exception, match="--precisions"):
        bt.parse_precisions("fp32,fp16", "cpu")  # fp16 autocast is a GPU setting
    out = tmp_path / "b"
    assert main(["bench", "train", "--presets", "fast", "--batches", "1x32,2x16", "--steps", "2", "--warmup", "1",
                 "--profile", "1", "--resolution", "16", "--out", str(out)]) == 0
    rows = list(csv.DictReader(open(out / "bench_train.csv")))
    assert [(r["objects_per_step"], r["rays_per_object"]) for r in rows] == [("1", "32"), ("2", "16")]
    for r in rows:
        sps, rps = float(r["steps_per_s"]), float(r["rays_per_s"])
        assert sps > 0 and rps == pytest.approx(sps * 32, rel=1e-3)
        assert float(r["cpu_seconds_per_step"]) > 0 and r["gpu_util_pct"] == "" and int(r["params"]) > 0
        assert 0 < float(r["draw_share"]) < 1
        # --profile: the profiled step's operator calls; no CUDA runtime calls and no device time on the CPU
        assert float(r["aten_ops_per_step"]) > 100
        assert float(r["kernel_launches_per_step"]) == float(r["syncs_per_step"]) == 0 and r["device_ms_per_step"] == ""
    # two objects a step call the model twice: about twice the operators of one
    assert 1.5 < float(rows[1]["aten_ops_per_step"]) / float(rows[0]["aten_ops_per_step"]) < 2.5
    table = (out / "bench_train_profile.txt").read_text()
    assert table.count("== fast") == 2 and "1x32 fp32 cpu" in table and "aten::" in table and "Self CPU" in table
    from blender_mrvm.training.trainer import RayBatcher

    assert RayBatcher.draw.__name__ == "draw"  # the timing wrapper is gone afterwards
    assert "steps/s" in capsys.readouterr().out
    assert main(["bench", "train", "--presets", "fast", "--batches", "1x0", "--out", str(tmp_path / "c")]) == 2
    assert not (tmp_path / "c").exists()
    for bad in (["--warmup", "0"], ["--profile", "-1"]):  # the first step carries the set-up: never timed
        assert main(["bench", "train", "--presets", "fast", *bad, "--out", str(tmp_path / "c")]) == 2
    assert not (tmp_path / "c").exists()


def test_bench_train_times_the_lpips_patch_recipe(tmp_path):
    """`bench train --lpips-weight`: the shipped recipe's step (one P x P patch per object scored by LPIPS-VGG)
    is timed and the row says so; a ray count that is no P x P patch with P >= 16 is one error before any
    work."""
    import csv

    from blender_mrvm.bench import train as bt
    from blender_mrvm.cli import main

    assert bt.patch_side(256) == 16 and bt.patch_side(1024) == 32
    for bad in (255, 100, 225):
        with pytest.raises(Exception, match="P >= 16"):
            bt.patch_side(bad)
    out = tmp_path / "b"
    assert main(["bench", "train", "--presets", "fast", "--batches", "2x256", "--steps", "1", "--warmup", "1",
                 "--resolution", "16", "--lpips-weight", "1", "--out", str(out)]) == 0
    (row,) = list(csv.DictReader(open(out / "bench_train.csv")))
    assert row["lpips_weight"] == "1.0" and float(row["rays_per_s"]) > 0
    for bad in (["--batches", "2x100"], ["--lpips-weight", "-1"]):
        assert main(["bench", "train", "--presets", "fast", "--lpips-weight", "1", *bad,
                     "--out", str(tmp_path / "c")]) == 2
    assert not (tmp_path / "c").exists()


def test_bench_train_compiles_on_request_and_needs_no_openexr(tmp_path, monkeypatch):
    """`bench train --compile` trains with the networks compiled (train.compile; recorded here instead of
    compiled: minutes on this CPU) and says so per row; its analytic set has no depth or normal EXRs, so it runs
    where OpenEXR is missing (the GPU machine: session 20's first call failed on exactly that)."""
    import csv

    import blender_mrvm.datasets.format as F
    from blender_mrvm.cli import main

    def no_openexr(*a, **k):
        raise ModuleNotFoundError("No module named 'OpenEXR'")

    monkeypatch.setattr(F, "exr_writer", no_openexr)
    seen = []
    monkeypatch.setattr(torch.nn.Module, "compile", lambda m, **kw: seen.append(type(m).__name__))
    out = tmp_path / "b"
    assert main(["bench", "train", "--presets", "fast", "--batches", "1x16", "--steps", "1", "--warmup", "1",
                 "--resolution", "16", "--compile", "--out", str(out)]) == 0
    assert [r["compiled"] for r in csv.DictReader(open(out / "bench_train.csv"))] == ["True"]
    assert seen == ["StreamBranch", "StreamBranch", "MRVMHead"]


def test_bench_model_writes_a_row_per_configuration_and_compiles_only_on_request(tmp_path, monkeypatch):
    """`bench model`: one row per preset x size x references x precision, rays evaluated within the view's; with
    `--compile` each network but the image encoder goes through nn.Module.compile (recorded here instead: compiling
    takes minutes on this CPU; the GPU session measures what it buys) and the row says so; `--profile` adds one
    profiled render's operator counts and its table."""
    import csv

    from blender_mrvm.cli import main
    from blender_mrvm.models import registry

    out = tmp_path / "m"
    args = ["bench", "model", "--presets", "fast", "--views", "1,2", "--sizes", "16", "--repeats", "1", "--threads",
            "1", "--out", str(out)]
    assert main(args) == 0
    rows = list(csv.DictReader(open(out / "bench_model.csv")))
    assert [(r["ref_views"], r["size"], r["compiled"]) for r in rows] == [("1", "16", "False"), ("2", "16", "False")]
    for r in rows:
        assert float(r["seconds_median"]) > 0 and 0 < int(r["rays_evaluated"]) <= int(r["rays_total"]) == 256
        assert "aten_ops_per_view" not in r
    assert not (out / "bench_model_profile.txt").exists()
    seen = []
    monkeypatch.setattr(torch.nn.Module, "compile", lambda m, **kw: seen.append((type(m).__name__, kw)))
    assert main([*args[:5], "2", *args[6:], "--force", "--compile", "--profile"]) == 0
    rows = list(csv.DictReader(open(out / "bench_model.csv")))
    assert [r["compiled"] for r in rows] == ["True"]
    assert float(rows[0]["aten_ops_per_view"]) > 100 and float(rows[0]["kernel_launches_per_view"]) == 0
    table = (out / "bench_model_profile.txt").read_text()
    assert table.startswith("== fast 16px 2 ref(s) fp32 cpu compiled=True") and "aten::" in table
    names = [n for n, _ in seen]
    assert "StreamBranch" in names and not any("Encoder" in n for n in names)
    assert all(kw == {"dynamic": True} for _, kw in seen)
    model = torch.nn.Module()
    model.encoder, model.coarse, model.act = torch.nn.Linear(2, 2), torch.nn.Linear(2, 2), torch.nn.ReLU()
    seen.clear()
    assert registry.compile_networks(model, mode="max-autotune") == ["coarse"]  # not the encoder nor a weightless module
    assert seen == [("Linear", {"dynamic": True, "mode": "max-autotune"})]
    seen.clear()
    assert main([*args[:5], "2", *args[6:], "--compile-mode", "reduce-overhead"]) == 2  # the results are kept...
    assert main([*args[:5], "2", *args[6:], "--compile-mode", "reduce-overhead", "--force"]) == 0  # ...or replaced
    assert not (out / "bench_model_profile.txt").exists()  # the earlier run's, not of these rows
    row = next(csv.DictReader(open(out / "bench_model.csv")))
    assert row["compiled"] == "True" and row["compile_mode"] == "reduce-overhead"
    assert seen and all(kw == {"dynamic": True, "mode": "reduce-overhead"} for _, kw in seen)
    monkeypatch.undo()
    assert main([*args[:5], "2", *args[6:], "--force", "--precisions", "fp32,int8"]) == 0  # int8 linear layers (CPU only)
    assert [r["precision"] for r in csv.DictReader(open(out / "bench_model.csv"))] == ["fp32", "int8"]
    assert main([*args[:5], "2", *args[6:], "--precisions", "int8", "--compile"]) == 2
    assert main([*args[:5], "2", *args[6:], "--precisions", "fp16"]) == 2  # a GPU setting


def test_compiling_keeps_the_state_dict_and_the_outputs():
    """compile_networks compiles in place (nn.Module.compile): the state dict keeps its keys, so a compiled
    training run writes the same checkpoints; no forward runs here, so nothing is actually compiled."""
    from blender_mrvm.models import registry

    model = registry.build_model(registry.build_config(None, "fast"))
    keys = list(model.state_dict())
    assert registry.compile_networks(model) == ["coarse", "fine", "mrvm"]
    assert list(model.state_dict()) == keys


def test_cudnn_attention_is_kept_out_unless_asked(monkeypatch):
    """Building a model turns cuDNN's attention off (it builds a graph per tensor shape: session 20 measured the
    host spending 28-35 ms in each bf16 attention call); MRVM_CUDNN_ATTENTION=1 keeps it."""
    from blender_mrvm.models import registry
    from blender_mrvm.models.nerformer import CUDNN_ATTENTION_ENV, configure_attention

    monkeypatch.delenv(CUDNN_ATTENTION_ENV, raising=False)
    torch.backends.cuda.enable_cudnn_sdp(True)
    registry.build_model(registry.build_config("gpnr", "fast"))  # any kind
    assert not torch.backends.cuda.cudnn_sdp_enabled()
    monkeypatch.setenv(CUDNN_ATTENTION_ENV, "1")
    assert configure_attention() and torch.backends.cuda.cudnn_sdp_enabled()
    monkeypatch.setenv(CUDNN_ATTENTION_ENV, "0")
    assert not configure_attention() and not torch.backends.cuda.cudnn_sdp_enabled()


def test_mrvm_budgets_table_pairs_the_arms_and_names_a_gpu_budget_batch(tmp_path):
    """scripts/mrvm_budgets_table.py: MRVM minus base per seed, budget and reference count; the GPU runs of
    `gpu_session.sh mrvm_scale` (``budget_all_gpu_*``) get their own rows, with the batch read from the checkpoint,
    and so do runs with the official finetune (``budget_oft_*``)."""
    import importlib.util

    from blender_mrvm.models.config import model_config
    from blender_mrvm.models.model import GeneralizableNeRF
    from blender_mrvm.training import checkpoint as ckpt

    spec = importlib.util.spec_from_file_location("mrvm_budgets_table", ROOT / "scripts" / "mrvm_budgets_table.py")
    table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(table)
    mcfg = model_config("fast")
    run = tmp_path / "run"
    ckpt.save_checkpoint(run, 1, GeneralizableNeRF(mcfg), mcfg, None,
                         {"train_config": json.dumps({"objects_per_step": 16, "rays_per_object": 4096})})

    def report(psnr: list[float], path: Path) -> dict:
        views = [{"category": "chair", "object": f"o{i // 2}", "view": i % 2, "psnr": p, "ssim": 0.5, "lpips": 0.3}
                 for i, p in enumerate(psnr)]
        return {"checkpoint": {"path": str(path)}, "views": views,
                "overall": {"psnr": float(np.mean(psnr)), "ssim": 0.5, "lpips": 0.3,
                            "baseline_nearest": {"psnr": 15.0, "lpips": 0.24}}}

    for name, arm, psnr in (("budget_all_gpu_{}_s0_p240_2v", "mrvm", [21, 22, 20, 21]),
                            ("budget_all_gpu_{}_s0_p240_2v", "base", [20, 21, 20, 20]),
                            ("budget_all_{}_s1_p9000_2v", "mrvm", [20, 20, 20, 20]),
                            ("budget_all_{}_s1_p9000_2v", "base", [20, 20, 21, 21]),
                            ("budget_all_r1024_{}_s2_p1000_1v", "mrvm", [20, 20, 20, 20]),
                            ("budget_all_r1024_{}_s2_p1000_1v", "base", [19, 19, 19, 19]),
                            ("budget_oft_{}_s0_p1000_2v", "mrvm", [20, 21, 20, 21]),
                            ("budget_oft_{}_s0_p1000_2v", "base", [20, 20, 20, 20]),
                            ("budget_oft_{}_s1_p1000_2v", "mrvm", [20, 20, 20, 20]),
                            ("budget_oft_{}_s1_p1000_2v", "base", [20, 20, 20, 20])):
        d = tmp_path / "eval" / name.format(arm)
        d.mkdir(parents=True)
        (d / "eval.json").write_text(json.dumps(report(psnr, run if "gpu" in name else tmp_path / "gone")))
    per_seed, _, seeds = table.main(tmp_path / "eval").partition("mean over seeds")
    assert per_seed == table.main(tmp_path / "eval", seeds=False) + "\nMRVM minus none, "
    rows = per_seed.splitlines()[2:-2]
    assert len(rows) == 5
    # FT=official runs of scripts/mrvm_budgets.sh: the official finetune, 2P steps, in their own rows
    assert rows[0].startswith("| unseen, official finetune (2P at lr 1e-3) | 0 | 1000 + 2000 = 3000 | 2 | 4 |")
    assert "| +0.500 [" in rows[0] and "| +0.000 [" in rows[1]
    # the seeds' table: one row per setting, budget and reference count; mean and SE over the seeds
    means = seeds.splitlines()[4:]
    assert len(means) == 4
    assert means[0] == ("| unseen, official finetune (2P at lr 1e-3) | 1000 + 2000 = 3000 | 2 | 0, 1 "
                        "| +0.250 (0.250) | +0.000 (0.000) | +0.000 (0.000) |")
    assert means[1].startswith("| all | 9000 + 3000 = 12000 | 2 | 1 | -0.500 |")
    rows = rows[2:]
    assert rows[0].startswith("| all | 1 | 9000 + 3000 = 12000 | 2 | 4 |") and "| -0.500 [" in rows[0]
    # RAYS=1024 runs of scripts/mrvm_budgets.sh: their own rows (the checkpoint is gone, so the name gives the rays)
    assert rows[1].startswith("| all, 1024 rays per object a step | 2 | 1000 + 333 = 1333 | 1 | 4 |") and "| +1.000" in rows[1]
    assert rows[2].startswith("| all, GPU 16 x 4096 rays a step | 0 | 240 + 80 = 320 | 2 | 4 |") and "| +0.750 [" in rows[2]


def test_bench_train_sweeps_object_batches(tmp_path):
    """`bench train --object-batches 1,8`: a row each; 8 objects a step rendered in shared forward passes (grouped by
    reference count) call far fewer operators per step than one pass per object, the lever for a GPU that waits on
    launches; a bad list is one error before any work."""
    import csv

    from blender_mrvm.bench import train as bt
    from blender_mrvm.cli import main

    assert bt.parse_object_batches("1, 8") == [1, 8]
    for bad in ("0", "a", "", "2,-1"):
        with pytest.raises(Exception, match="--object-batches"):
            bt.parse_object_batches(bad)
    out = tmp_path / "b"
    assert main(["bench", "train", "--presets", "fast", "--batches", "8x32", "--object-batches", "1,8", "--steps", "1",
                 "--warmup", "1", "--profile", "1", "--resolution", "16", "--ref-views-per", "object,step",
                 "--out", str(out)]) == 0
    one, one_step, many, many_step = list(csv.DictReader(open(out / "bench_train.csv")))
    assert [(r["object_batch"], r["ref_views_per"]) for r in (one, one_step, many, many_step)] == [
        ("1", "object"), ("1", "step"), ("8", "object"), ("8", "step")]
    assert float(many["aten_ops_per_step"]) < 0.6 * float(one["aten_ops_per_step"])
    # one reference count a step: one forward pass, fewer operators again
    assert float(many_step["aten_ops_per_step"]) < 0.8 * float(many["aten_ops_per_step"])
    for bad in (["--object-batches", "0"], ["--ref-views-per", "batch"]):
        assert main(["bench", "train", "--presets", "fast", *bad, "--out", str(tmp_path / "c")]) == 2
    assert not (tmp_path / "c").exists()


def test_a_bench_keeps_its_earlier_results_unless_forced(tmp_path, capsys):
    """Every bench refuses an --out holding its own earlier results (it had overwritten them), before measuring;
    --force removes them when the measuring starts, so a stopped rerun never mixes its rows with an earlier
    run's plot or front. Files of other benches or the user's stay."""
    from blender_mrvm.bench import start_results
    from blender_mrvm.cli import main
    from blender_mrvm.errors import OutputError

    out = tmp_path / "b"
    out.mkdir()
    for n in (*tr.RESULTS, "bench_model.csv", "notes.md"):
        (out / n).write_text("earlier")
    with pytest.raises(OutputError, match=r"already holds this bench's results \(bench_tradeoff.csv, "):
        start_results(out, tr.RESULTS)
    assert main(["bench", "profile", "--presets", "fast", "--size", "8", "--out", str(out)]) == 0  # its own CSV is not there
    capsys.readouterr()
    assert main(["bench", "profile", "--presets", "fast", "--size", "8", "--out", str(out)]) == 2
    assert "pass --force" in capsys.readouterr().err
    start_results(out, tr.RESULTS, force=True)
    assert sorted(p.name for p in out.iterdir()) == ["bench_model.csv", "bench_profile.csv", "notes.md"]


def test_empty_lists_are_refused_and_write_csv_keeps_the_earlier_file(tmp_path):
    from blender_mrvm.bench import names, write_csv

    for text in (",", " , ", ""):
        with pytest.raises(InputError, match="--presets: none given"):
            names(text, "--presets")
    assert names(" fast, gpnr:fast ,", "--presets") == ["fast", "gpnr:fast"]
    with pytest.raises(InputError, match="--engines: unknown FOO; choose from A, B"):
        names("A,FOO", "--engines", ("A", "B"))
    (tmp_path / "x.csv").write_text("a\n1\n")
    with pytest.raises(InputError, match="nothing was measured"):
        write_csv(tmp_path / "x.csv", [])
    assert (tmp_path / "x.csv").read_text() == "a\n1\n"


def test_tradeoff_skips_the_points_objects_with_few_views_cannot_make(tmp_path, capsys):
    """The refs axis's 5 references on objects of 4 views (no target left: an IndexError) and the nearest points
    above 3 are skipped with a note; the rest is measured."""
    import csv

    from blender_mrvm.cli import main
    from blender_mrvm.datasets import format as F
    from blender_mrvm.training.synthetic import make_sphere_dataset

    data = make_sphere_dataset(tmp_path / "ds", n_objects=1, n_views=4, resolution=16, seed=1)
    F.write_split(data, "test", F.read_split(data, "train"))
    assert [tr.fits(tr.Point("refs", "", refs=r), 4) for r in (1, 2, 5)] == [True, True, False]
    assert [tr.fits(tr.Point("nearest", "", nearest=k), 4) for k in (2, 3, 5)] == [True, True, False]
    out = tmp_path / "b"
    assert main(["bench", "tradeoff", "--data", str(data), "--checkpoints", "shipped:gpnr", "--axes", "refs",
                 "--objects", "1", "--targets", "1", "--size", "8", "--repeats", "1", "--no-lpips",
                 "--out", str(out)]) == 0
    assert "'5 refs' skipped: the objects have 4 views" in capsys.readouterr().out
    assert [r["point"] for r in csv.DictReader(open(out / "bench_tradeoff.csv"))] == ["as trained", "1 refs"]


def test_bench_threads_runs_each_load_once_and_a_failed_child_is_one_line(monkeypatch, tmp_path):
    """--competitors 0: the quiet settings once (they had run twice); ratio_to_first is to the first --threads
    count; a failing child `bench model` is an error naming its own error line, not a CalledProcessError."""
    import argparse
    import csv

    from blender_mrvm.bench import threads as bt
    from blender_mrvm.errors import MRVMError

    monkeypatch.setattr(bt, "_one", lambda policy, t, args: 0.5 * t)
    args = argparse.Namespace(preset="fast", size=8, views=1, threads="2,4", competitors=0, repeats=1,
                              out=str(tmp_path / "t"), force=False)
    assert bt.run(args) == 0
    rows = list(csv.DictReader(open(tmp_path / "t" / "bench_threads.csv")))
    assert len(rows) == 2 * len(bt.POLICIES) and {r["competing_processes"] for r in rows} == {"0"}
    assert [r["ratio_to_first"] for r in rows[:2]] == ["1.0", "2.0"] and "ratio to the first of" in bt.__doc__
    monkeypatch.undo()
    with pytest.raises(MRVMError, match=r"failed with exit code 2: --views: each must be at least 1"):
        bt._one("PASSIVE", 1, argparse.Namespace(preset="fast", size=8, views=0, repeats=1))


def test_bench_capture_caches_a_ring_per_render_setting(tmp_path):
    import argparse

    from blender_mrvm.bench import capture as bc

    a = argparse.Namespace(views=3, width=16, height=16, samples=1)
    b = argparse.Namespace(views=3, width=16, height=16, samples=4)
    assert bc.ring_folder(tmp_path, a) != bc.ring_folder(tmp_path, b)


def test_bench_train_refuses_an_unknown_device_before_making_its_folder(tmp_path, capsys):
    """`bench train --device tpu` was refused only after --out was made: an empty folder was left behind."""
    from blender_mrvm.cli import main

    assert main(["bench", "train", "--device", "tpu", "--out", str(tmp_path / "new")]) == 2
    assert "unknown device 'tpu'" in capsys.readouterr().err and not (tmp_path / "new").exists()
