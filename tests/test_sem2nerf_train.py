"""Sem2NeRF training: 2 CPU steps on a tiny analytic dataset, checkpoints, resume, patch sampling."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from blender_mrvm.errors import InputError
from blender_mrvm.progress import run_to_end
from blender_mrvm.training import sem2nerf as T

torch.set_num_threads(1)

TINY_MODEL = (("hidden", 16), ("n_layers", 2), ("encoder_hidden", 32), ("vgg_layers", 4), ("n_coarse", 6),
              ("n_fine", 2), ("style_mean_samples", 200), ("z_dim", 8), ("mapping_hidden", 16))


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    from blender_mrvm.training.synthetic import make_sphere_dataset

    return make_sphere_dataset(tmp_path_factory.mktemp("s2n") / "d", n_objects=3, n_views=4, resolution=16)


def test_scale_range_anneals():
    cfg = T.train_config(scale_anneal_steps=100.0)
    assert T.scale_lower_bound(0, cfg) == pytest.approx(0.9)
    vals = [T.scale_lower_bound(s, cfg) for s in (0, 50, 100, 400, 5000)]
    assert all(a > b for a, b in zip(vals, vals[1:]))
    assert T.scale_lower_bound(100, cfg) == pytest.approx(0.06 + 0.84 / np.e)
    assert vals[-1] == pytest.approx(0.06, abs=1e-6)


def test_patch_sampling_region_aware_and_scaled():
    rng = np.random.default_rng(0)
    mask = np.zeros((64, 64), np.uint8)
    mask[40:50, 5:15] = 2
    px = T.sample_patch(rng, mask, 8, 0.25, fg_prob=1.0)
    assert px.shape == (64, 2)
    assert px.min() >= 0 and px.max() <= 64
    span = px.max(0) - px.min(0)
    assert np.allclose(span, 0.25 * 64 * 7 / 8)  # P samples spaced scale * side / P apart
    # centred on an object pixel: the patch overlaps the object
    xi, yi = px[:, 0].astype(int), px[:, 1].astype(int)
    assert (mask[yi, xi] > 0).any()
    full = T.sample_patch(rng, mask, 8, 1.0, fg_prob=0.0)
    assert np.allclose(np.unique(full[:, 0]), (np.arange(8) + 0.5) * 8)


def test_two_step_training_checkpoint_and_resume(data, tmp_path):
    from blender_mrvm.models.sem2nerf.inputs import build_inputs

    out = tmp_path / "run"
    cfg = T.train_config(data=str(data), out_dir=str(out), preset="fast", model_overrides=TINY_MODEL, iterations=2,
                         objects_per_step=2, patch_size=16, checkpoint_every=2, log_every=1, threads=1)
    summary = run_to_end(T.train(cfg, resume=False))
    assert summary["step"] == 2 and summary["objects"] == 2
    lines = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in lines] == [1, 2]
    assert all(np.isfinite(r["loss"]) and r["lpips"] > 0 and r["ce"] > 0 for r in lines)
    model, mcfg, meta = T.load_sem2nerf(out)
    assert meta["model_kind"] == "sem2nerf" and meta["train_image_size"] == "16"
    assert mcfg.labels[0] == 0 and set(mcfg.labels) >= {1}
    assert mcfg.image_size == 16 and mcfg.hidden == 16
    assert json.loads(meta["model_config"])["labels"] == list(mcfg.labels)
    # the loaded model renders the training mask's input view
    from blender_mrvm.training.sem2nerf import load_masked_object

    ob = load_masked_object(sorted(data.glob("spheres/obj*"))[0])
    code = model.encode(torch.from_numpy(build_inputs(ob.masks[0], mcfg.labels))[None], ob.c2w[:1], ob.intrinsics[0])
    img = model.render_image(ob.intrinsics[0], ob.c2w[0], code, model.default_style())
    assert img["rgb"].shape == (16, 16, 3) and torch.isfinite(img["rgb"]).all()
    assert not any(p.name.startswith(".") for p in (out / "checkpoints").iterdir())
    # resume continues from step 2 and ends at 3
    cfg3 = T.train_config(**{**cfg.__dict__, "iterations": 3, "lr": 7e-4})
    s3 = run_to_end(T.train(cfg3, resume=True))
    assert s3["resumed_from"] and s3["step"] == 3
    st = torch.load(out / "checkpoints" / "step_0000003" / "trainer_state.pt", weights_only=True)
    assert st["opt"]["param_groups"][0]["lr"] == 7e-4  # the config's learning rate applies on resume
    assert st["opt"]["param_groups"][1]["lr"] == cfg.encoder_lr
    assert (out / "checkpoints" / "latest").read_text().strip() == "step_0000003"


def test_discriminator_option_runs(data, tmp_path):
    cfg = T.train_config(data=str(data), out_dir=str(tmp_path / "gan"), preset="fast", model_overrides=TINY_MODEL,
                         iterations=1, objects_per_step=1, patch_size=8, lpips_weight=0.0, gan_weight=0.1,
                         checkpoint_every=1, log_every=1, threads=1)
    run_to_end(T.train(cfg, resume=False))
    rec = json.loads((tmp_path / "gan" / "metrics.jsonl").read_text().splitlines()[-1])
    assert rec["d_loss"] > 0 and rec["g_adv"] > 0
    st = torch.load(tmp_path / "gan" / "checkpoints" / "step_0000001" / "trainer_state.pt", weights_only=True)
    assert "disc" in st


def test_not_a_sem2nerf_checkpoint(tmp_path):
    with pytest.raises(InputError):
        T.load_sem2nerf(tmp_path)
    with pytest.raises(InputError, match="LPIPS"):
        T.train_config(patch_size=8)


def test_training_reduces_losses_on_one_object(data, tmp_path):
    cfg = T.train_config(data=str(data), out_dir=str(tmp_path / "fit"), preset="fast", model_overrides=TINY_MODEL,
                         iterations=60, max_objects=1, objects_per_step=1, other_views=1, patch_size=8,
                         lpips_weight=0.0, ce_weight=0.5, lr=1e-3, encoder_lr=1e-3, checkpoint_every=1000,
                         log_every=1, threads=1, seed=1)
    run_to_end(T.train(cfg, resume=False))
    rows = [json.loads(x) for x in (tmp_path / "fit" / "metrics.jsonl").read_text().splitlines()]
    first, last = rows[:10], rows[-10:]
    assert np.mean([r["l2"] for r in last]) < 0.7 * np.mean([r["l2"] for r in first])
    assert np.mean([r["ce"] for r in last]) < 0.85 * np.mean([r["ce"] for r in first])


def test_miou_and_category_means():
    gt = np.array([[0, 1], [2, 2]])
    assert T.miou(gt, gt) == 1.0
    assert T.miou(gt, np.array([[0, 1], [2, 0]])) == pytest.approx((1 / 2 + 1 + 1 / 2) / 3)
    ims = np.ones((2, 2, 2, 3), np.float32)
    ims[0, 0, 0] = 0.2
    ims[1, 0, 0] = 0.6
    masks = np.zeros((2, 2, 2), np.uint8)
    masks[:, 0, 0] = 1
    o = T.MaskedObject("a", "cat", ims, masks, np.tile(np.eye(4), (2, 1, 1)), [None, None], {})
    mean = T.category_mean_images([o])["cat"]
    assert np.allclose(mean[0, 0], 0.4) and np.allclose(mean[1, 1], 0.4)  # uncovered pixels: overall object mean
    photo = T.category_mean_photos([o])["cat"]  # no mask: the background counts too
    assert np.allclose(photo[0, 0], 0.4) and np.allclose(photo[1, 1], 1.0)


def test_input_weight_and_lr_decay(data, tmp_path):
    """--lr-end-factor decays every learning rate exponentially to that factor at the last step;
    --input-weight is validated through the same config and the run stays finite."""
    cfg = T.train_config(data=str(data), out_dir=str(tmp_path / "d"), preset="fast", model_overrides=TINY_MODEL,
                         iterations=2, objects_per_step=1, patch_size=8, lpips_weight=0.0, input_weight=3.0,
                         lr=1e-3, encoder_lr=4e-4, code_lr=2e-3, lr_end_factor=0.25, checkpoint_every=2,
                         log_every=1, threads=1)
    run_to_end(T.train(cfg, resume=False))
    st = torch.load(tmp_path / "d" / "checkpoints" / "step_0000002" / "trainer_state.pt", weights_only=True)
    lrs = [g["lr"] for g in st["opt"]["param_groups"]]
    assert lrs == pytest.approx([1e-3 * 0.25, 4e-4 * 0.25, 2e-3 * 0.25])  # the last step ran at the end factor
    rows = [json.loads(x) for x in (tmp_path / "d" / "metrics.jsonl").read_text().splitlines()]
    assert all(np.isfinite(r["loss"]) for r in rows)


def test_model_overrides_on_the_command_line():
    from blender_mrvm.commands.sem2nerf import parse_model_overrides

    assert parse_model_overrides(["n_coarse=16", "pixel_aligned=false", "density_scale=5"]) == {
        "n_coarse": 16, "pixel_aligned": False, "density_scale": 5.0}
    for bad in ("nope=1", "n_coarse", "n_coarse=x", "pixel_aligned=maybe", "labels=1"):
        with pytest.raises(InputError, match="--model"):
            parse_model_overrides([bad])


def test_style_codes_learn_each_objects_appearance(data, tmp_path):
    """Two objects with the same shape, masks and poses but different colours: only the per-object code can
    tell them apart, so after training each object's learned style must render its own colours better than
    the other's (a generator that ignored its style would render one image for both, which cannot pass)."""
    from dataclasses import replace as dc_replace

    from blender_mrvm.models.checkpoint_files import find_checkpoint

    (a,) = T.load_masked_dataset(data, "train", limit=1)
    fg = a.masks[..., None] > 0
    b = dc_replace(a, name="recoloured", images=np.where(fg, a.images[..., ::-1] * 0.5, a.images).astype(np.float32))
    # 200 steps with faster codes: at 120 steps and the default code lr the margin was 0.86 against the 0.85
    # asked on one machine and passed on another (float order); here seeds 3-6 give 0.60-0.69 (measured).
    cfg = T.train_config(out_dir=str(tmp_path / "st"), preset="fast", model_overrides=TINY_MODEL, iterations=200,
                         code_lr=1e-2,
                         objects_per_step=2, other_views=1, patch_size=8, lpips_weight=0.0, ce_weight=0.1,
                         lr=2e-3, encoder_lr=1e-3, checkpoint_every=1000, threads=1, seed=3)
    run_to_end(T.train(cfg, resume=False, objects=[a, b]))
    ck = find_checkpoint(tmp_path / "st")
    model, mcfg, _ = T.load_sem2nerf(ck)
    codes = torch.load(ck / "trainer_state.pt", weights_only=True)["codes"]
    from blender_mrvm.models.sem2nerf.inputs import build_inputs

    v = 0
    with torch.no_grad():
        mc = model.encode(torch.from_numpy(build_inputs(a.masks[v], mcfg.labels))[None], a.c2w[v][None], a.intrinsics[v])
        styles = T.code_styles(model, codes)
        ims = [model.render_image(a.intrinsics[v], a.c2w[v], mc, styles[i:i + 1])["rgb"].numpy() for i in (0, 1)]
    err = [[float(((ims[i] - o.images[v])[fg[v, ..., 0]] ** 2).mean()) for o in (a, b)] for i in (0, 1)]
    print("object-pixel MSE [style][object]", err)
    assert err[0][0] < 0.85 * err[0][1] and err[1][1] < 0.85 * err[1][0]


def test_init_checkpoint_adds_the_style_colour_head(data, tmp_path):
    """--init fine-tunes an older model (trained without per-part style colours) with the head added at
    zero: before any step it renders exactly as the old model; training moves the head; an override that
    changes a weight's shape is a one-line InputError."""
    old_cfg = T.train_config(data=str(data), out_dir=str(tmp_path / "old"), preset="fast",
                             model_overrides=TINY_MODEL + (("style_part_colours", False),), iterations=2,
                             objects_per_step=2, patch_size=8, lpips_weight=0.0, checkpoint_every=1000, threads=1)
    run_to_end(T.train(old_cfg, resume=False))
    old, ocfg, _ = T.load_sem2nerf(tmp_path / "old")
    new, ncfg, codes = T.init_model(tmp_path / "old", {"style_part_colours": True})
    objs = T.load_masked_dataset(data, "train")
    assert not ocfg.style_part_colours and ncfg.style_part_colours and codes is not None and codes.shape[0] == len(objs)
    from blender_mrvm.models.sem2nerf.inputs import build_inputs

    o, v = objs[0], 1
    with torch.no_grad():
        inp = torch.from_numpy(build_inputs(o.masks[v], ocfg.labels))[None]
        a = old.render_image(o.intrinsics[v], o.c2w[v], old.encode(inp, o.c2w[v][None], o.intrinsics[v]),
                             old.style_from_seed(4))["rgb"]
        new.eval()
        b = new.render_image(o.intrinsics[v], o.c2w[v], new.encode(inp, o.c2w[v][None], o.intrinsics[v]),
                             new.style_from_seed(4))["rgb"]
    assert torch.allclose(a, b, atol=1e-6)
    ft = T.train_config(data=str(data), out_dir=str(tmp_path / "ft"), init_checkpoint=str(tmp_path / "old"),
                        model_overrides=(("style_part_colours", True),), iterations=3, objects_per_step=2,
                        patch_size=8, lpips_weight=0.0, code_lr=0.03, checkpoint_every=1000, threads=1)
    run_to_end(T.train(ft, resume=False))
    tuned, tcfg, _ = T.load_sem2nerf(tmp_path / "ft")
    assert tcfg.style_part_colours and float(tuned.field.style_part_rgb.weight.detach().abs().sum()) > 0
    with pytest.raises(InputError, match="does not fit"):
        T.init_model(tmp_path / "old", {"hidden": 8})


def test_a_run_closed_between_checkpoints_keeps_its_steps(data, tmp_path, capsys):
    """Ctrl-C or the panel's Esc (the generator closed after a step) saves that step; the run resumes there."""
    out = tmp_path / "run"
    cfg = T.train_config(data=str(data), out_dir=str(out), preset="fast", model_overrides=TINY_MODEL, iterations=5,
                         objects_per_step=2, patch_size=16, checkpoint_every=100, log_every=1, threads=1)
    gen = T.train(cfg, resume=False)
    next(gen), next(gen)
    gen.close()
    assert (out / "checkpoints" / "latest").read_text().strip() == "step_0000002"
    assert "stopped after step 2 of 5" in capsys.readouterr().err
    s = run_to_end(T.train(T.train_config(**{**cfg.__dict__, "iterations": 3}), resume=True))
    assert s["step"] == 3 and (out / "checkpoints" / "latest").read_text().strip() == "step_0000003"


def test_no_resume_refuses_a_run_unless_forced_and_resume_drops_metrics_past_its_checkpoint(data, tmp_path):
    """Without resume a folder holding a run is refused (nothing touched); with force the old run is removed first,
    so its later checkpoints cannot outrank the new run's and metrics.jsonl holds the new run's steps only. A
    resume drops the metrics a run wrote past the checkpoint it resumes from."""
    from blender_mrvm.models.checkpoint_files import find_checkpoint

    out = tmp_path / "run"

    def cfg(**kw):
        base = dict(data=str(data), out_dir=str(out), preset="fast", model_overrides=TINY_MODEL, iterations=4,
                    objects_per_step=1, patch_size=4, lpips_weight=0.0, checkpoint_every=2, log_every=1, threads=1)
        return T.train_config(**{**base, **kw})

    def steps():
        return [json.loads(x)["step"] for x in (out / "metrics.jsonl").read_text().splitlines()]

    run_to_end(T.train(cfg(), resume=False))
    import shutil

    shutil.rmtree(out / "checkpoints" / "step_0000004")  # killed after its metrics, before its checkpoint
    assert run_to_end(T.train(cfg(), resume=True))["resumed_from"] and steps() == [1, 2, 3, 4]
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    with pytest.raises(InputError, match="holds a run .checkpoints up to step 4.*--force"):
        run_to_end(T.train(cfg(iterations=2, checkpoint_every=1, seed=5), resume=False))
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    run_to_end(T.train(cfg(iterations=2, checkpoint_every=1, seed=5), resume=False, force=True))
    assert sorted(p.name for p in (out / "checkpoints").glob("step_*")) == ["step_0000001", "step_0000002"]
    assert find_checkpoint(out).name == "step_0000002" and steps() == [1, 2]


def test_a_nan_loss_or_a_diverged_update_stops_before_anything_is_saved(data, tmp_path):
    """A NaN loss had raised a raw RuntimeError ('loss became nan at step 1', 0-based) only after the generator's and
    the discriminator's updates, and a diverged update had been saved (weights and style mean non-finite). Now both
    stop with `train`'s one-line TrainingStopped, steps counted from 1, and no such weights are written."""
    from blender_mrvm.errors import TrainingStopped

    objects = T.load_masked_dataset(data)
    bad = [T.MaskedObject(o.name, o.category, np.full_like(o.images, np.nan), o.masks, o.c2w, o.intrinsics, o.labels)
           for o in objects]
    base = dict(data=str(data), preset="fast", model_overrides=TINY_MODEL, iterations=2, objects_per_step=1,
                patch_size=8, lpips_weight=0.0, gan_weight=0.1, checkpoint_every=1, log_every=1, threads=1)
    out = tmp_path / "nan"
    with pytest.raises(TrainingStopped, match=r"training stopped at step 1: the loss is nan .*no checkpoint was "
                                              r"written"):
        run_to_end(T.train(T.train_config(**base, out_dir=str(out)), resume=False, objects=bad))
    assert not (out / "checkpoints").exists()
    # a learning rate of 1e30 (refused by train_config, so built directly): the first update diverges
    out = tmp_path / "lr"
    cfg = T.Sem2NeRFTrainConfig(**{**base, "model_overrides": tuple(TINY_MODEL)}, out_dir=str(out), lr=1e30,
                                encoder_lr=1e30)
    with pytest.raises(TrainingStopped, match=r"training stopped at step 1: its update left NaN, infinite or diverged "
                                              r"weights .*no checkpoint was written"):
        run_to_end(T.train(cfg, resume=False, objects=objects))
    assert not (out / "checkpoints").exists()


@pytest.mark.parametrize("field,value", [("lr", 1e39), ("encoder_lr", 2.0), ("code_lr", float("nan")),
                                         ("disc_lr", -1.0), ("lr_end_factor", 1e39)])
def test_learning_rates_are_checked_up_front(field, value):
    """--lr 1e39 (not a float32) had crashed in Adam's step with a traceback, after the run folder was started."""
    with pytest.raises(InputError, match=f"--{field.replace('_', '-')} must be a number"):
        T.train_config(**{field: value})


def test_non_finite_weights_are_refused_and_nan_renders_name_the_checkpoint(tmp_path):
    """load_sem2nerf lacked the finiteness check `load_weights` makes (a NaN style mean loaded), and a model with
    diverged finite weights wrote its NaN renders as black images."""
    from blender_mrvm.models.sem2nerf.config import sem2nerf_config
    from blender_mrvm.models.sem2nerf.inputs import build_inputs
    from blender_mrvm.models.sem2nerf.model import Sem2NeRF

    cfg = sem2nerf_config("fast", dict(TINY_MODEL), image_size=16, labels=(0, 1), label_names=("background", "a"))
    model = Sem2NeRF(cfg)
    with torch.no_grad():
        model.style_mean.fill_(float("nan"))
    T.save_checkpoint(tmp_path / "nan", 1, model, 16, None)
    with pytest.raises(InputError, match="holds NaN or infinite weights \\(style_mean\\)"):
        T.load_sem2nerf(tmp_path / "nan")
    with torch.no_grad():
        model.update_style_mean()
        for p in model.parameters():
            p.fill_(1e30)
        model.style_mean.clamp_(-1e30, 1e30).nan_to_num_(0.0)
    ck = T.save_checkpoint(tmp_path / "huge", 1, model, 16, None)
    model, cfg, _ = T.load_sem2nerf(tmp_path / "huge")
    from blender_mrvm.geometry import cameras

    intr = cameras.intrinsics_from_fov(0.7, 16, 16)
    c2w = cameras.look_at_opencv(np.array([2.0, 0.0, 1.0]))
    mask = np.zeros((16, 16), np.uint8)
    mask[4:12, 4:12] = 1
    code = model.encode(torch.from_numpy(build_inputs(mask, cfg.labels))[None], c2w[None], intr)
    with pytest.raises(InputError, match=f"the checkpoint {ck / 'model.safetensors'} is probably broken"):
        model.render_image(intr, c2w, code, model.default_style())


def _tiny(data, out, **kw):
    base = dict(data=str(data), out_dir=str(out), preset="fast", model_overrides=TINY_MODEL, iterations=2,
                objects_per_step=1, patch_size=4, lpips_weight=0.0, checkpoint_every=1, log_every=1, threads=1)
    return T.train_config(**{**base, **kw})


def _files(folder):
    return {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_a_second_run_into_the_same_folder_is_refused_while_the_first_runs(data, tmp_path):
    """Two `sem2nerf train` into one run folder had both gone ahead (checkpoints overwriting each other, metrics.jsonl
    interleaved, config.json the last one's): the run folder is held for the whole run, as `train` holds it."""
    from blender_mrvm.errors import OutputError

    out = tmp_path / "run"
    first = T.train(_tiny(data, out, iterations=3, seed=1))
    next(first)  # step 1 done, the run goes on
    with pytest.raises(OutputError, match=f"run folder {out} is in use by another process"):
        run_to_end(T.train(_tiny(data, out, iterations=3, seed=2, lr=1e-3)))
    assert run_to_end(first)["step"] == 3
    assert json.loads((out / "config.json").read_text())["train"]["seed"] == 1
    assert [json.loads(x)["step"] for x in (out / "metrics.jsonl").read_text().splitlines()] == [1, 2, 3]
    assert not (out / ".lock").exists()  # released at the end: the next run goes ahead
    assert run_to_end(T.train(_tiny(data, out, iterations=4, seed=1)))["step"] == 4


def test_a_resume_on_other_objects_is_refused(data, tmp_path):
    """The checkpoint's per-object style codes belong to the objects it records: a resume on as many other objects
    had given them to the wrong objects silently. Refused in one line naming the first differing object."""
    objs = T.load_masked_dataset(data) + T.load_masked_dataset(data, "test")  # 3 objects
    out = tmp_path / "run"
    run_to_end(T.train(_tiny(data, out), objects=objs[:2]))
    before = _files(out)
    names = [f"{o.category}/{o.name}" for o in objs]
    with pytest.raises(InputError, match=f"its object 2 is {names[1]}, this data's is {names[2]}: resume it on the "
                                         "same objects .*--no-resume --force"):
        run_to_end(T.train(_tiny(data, out, iterations=3), objects=[objs[0], objs[2]]))
    with pytest.raises(InputError, match=f"this data has 1 more, the first {names[2]}"):
        run_to_end(T.train(_tiny(data, out, iterations=3), objects=objs))
    assert _files(out) == before
    assert run_to_end(T.train(_tiny(data, out, iterations=3), objects=objs[:2]))["step"] == 3


def test_a_resume_with_another_model_is_refused(data, tmp_path):
    """A resume had trained on as the checkpoint's model while config.json recorded the --preset / --model it was
    given. Refused before anything is written, naming the run's own options, as `train` refuses a resume whose model
    is not the run's; so is an --init the run did not begin from (`train`'s _check_continues)."""
    out = tmp_path / "run"
    run_to_end(T.train(_tiny(data, out, iterations=3)))
    before = _files(out)
    with pytest.raises(InputError, match=r"trains a sem2nerf model with preset=fast; this start \(--preset balanced\) "
                                         r"asks for preset=balanced and 9 more setting\(s\), which would not be used: "
                                         r"continue it with its own model \(--preset fast --model vgg_layers=4 "
                                         r"--model encoder_hidden=32 .*--model n_fine=2\), start over with "
                                         r"--no-resume --force, or give another --out"):
        run_to_end(T.train(_tiny(data, out, iterations=4, preset="balanced", model_overrides=())))
    with pytest.raises(InputError, match=r"with preset=fast; this start \(--preset balanced --model hidden=16 .*\) "
                                         r"asks for preset=balanced, which"):  # the same fields, another preset
        run_to_end(T.train(_tiny(data, out, iterations=4, preset="balanced")))
    with pytest.raises(InputError, match="with n_coarse=6; this start .* asks for n_coarse=8, which"):
        run_to_end(T.train(_tiny(data, out, iterations=4, model_overrides=TINY_MODEL + (("n_coarse", 8),))))
    with pytest.raises(InputError, match="began from a random initialisation, not --init"):
        run_to_end(T.train(_tiny(data, out, iterations=4, init_checkpoint=str(tmp_path / "other"))))
    assert _files(out) == before
    # the same options (the overrides in any order) continue it; a larger --iterations is fine
    s = run_to_end(T.train(_tiny(data, out, iterations=4, model_overrides=tuple(reversed(TINY_MODEL)))))
    assert s["step"] == 4 and json.loads((out / "config.json").read_text())["train"]["iterations"] == 4


def test_half_saved_checkpoints_of_a_killed_run_are_swept_at_the_next_start(data, tmp_path):
    """kill -9 during a checkpoint save leaves its temporary checkpoints/.step_* folder; the next start removes it
    under the run folder's lock (guards.sweep_partials, as `train`)."""
    out = tmp_path / "run"
    run_to_end(T.train(_tiny(data, out, iterations=1)))
    left = out / "checkpoints" / ".step_0000002.x1y2z3"
    left.mkdir()
    (left / "model.safetensors").write_bytes(b"half")
    run_to_end(T.train(_tiny(data, out, iterations=2)))
    assert not left.exists() and sorted(p.name for p in (out / "checkpoints").iterdir()) == [
        "latest", "step_0000001", "step_0000002"]


def test_a_fine_tune_gives_learned_codes_to_their_own_objects_only(data, tmp_path):
    """--init takes the per-object codes the checkpoint learned for the objects it trained, by name: on as many
    other objects they had been taken by position. A resume of the fine-tune without --init goes on (the run's own
    init recorded)."""
    objs = T.load_masked_dataset(data) + T.load_masked_dataset(data, "test")  # 3 objects
    run_to_end(T.train(_tiny(data, tmp_path / "old", iterations=1), objects=objs[:2]))
    old = torch.load(tmp_path / "old" / "checkpoints" / "step_0000001" / "trainer_state.pt", weights_only=True)
    ft = tmp_path / "ft"
    cfg = _tiny(data, ft, iterations=1, init_checkpoint=str(tmp_path / "old"), code_lr=0.0)
    run_to_end(T.train(cfg, objects=[objs[1], objs[2]]))
    new = torch.load(ft / "checkpoints" / "step_0000001" / "trainer_state.pt", weights_only=True)
    assert torch.equal(new["codes"][0], old["codes"][1])  # objs[1] keeps its own code
    assert not any(torch.equal(new["codes"][1], c) for c in old["codes"])  # objs[2]: a fresh one
    s = run_to_end(T.train(T.train_config(**{**cfg.__dict__, "init_checkpoint": "", "iterations": 2}),
                           objects=[objs[1], objs[2]]))
    assert s["step"] == 2
    assert json.loads((ft / "config.json").read_text())["train"]["init_checkpoint"] == str(tmp_path / "old")


def test_a_resume_below_the_runs_step_is_refused(data, tmp_path):
    """--iterations below the run's step had exited 0 with nothing trained and config.json recording the lower
    number; refused before anything is written, as `train` refuses it. The run's own step is fine (nothing to do)."""
    out = tmp_path / "run"
    run_to_end(T.train(_tiny(data, out, iterations=3)))
    before = _files(out)
    with pytest.raises(InputError, match=r"the run in .* is at step 3 \(step_0000003\), past --iterations \(2\): "
                                         r"raise it to 3 or more to continue the run, or start it over "
                                         r"\(--no-resume --force\)"):
        run_to_end(T.train(_tiny(data, out)))
    assert _files(out) == before
    assert run_to_end(T.train(_tiny(data, out, iterations=3)))["step"] == 3


def test_a_misspelt_split_is_refused_not_every_object(data):
    """``sem2nerf train --split trian`` trained on every object, test objects included, and ``sem2nerf eval --split
    tset`` scored them all, both exit 0 (no ``splits/<split>.lst``: every object): refused as ``eval`` refuses it."""
    from blender_mrvm.errors import InputError

    for typo in ("trian", "tset"):
        with pytest.raises(InputError, match=rf"has no split '{typo}' \(it has"):
            T.load_masked_dataset(data, typo)
