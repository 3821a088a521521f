"""Training leftovers: the losses a torchrun job logs, Sem2NeRF checkpoints' train record, GPNR's depth spacing when
an object model is fine-tuned on rooms."""

from __future__ import annotations

import os
import socket

import pytest
import torch
import torch.multiprocessing as mp

torch.set_num_threads(1)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _gather_rank(rank: int, world: int, port: int, parts: list, out: str) -> None:
    import json

    import torch.distributed as dist

    from blender_mrvm.training.trainer import _mean_over_ranks

    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    dist.init_process_group("gloo", rank=rank, world_size=world)
    try:
        got = _mean_over_ranks(parts[rank], world)
    finally:
        dist.destroy_process_group()
    with open(f"{out}.{rank}", "w") as f:
        json.dump(got, f)


def test_logged_losses_are_the_mean_over_the_ranks(tmp_path):
    """Under torchrun metrics.jsonl had recorded rank 0's losses (its own batch's) while the update is of every
    rank's mean gradient: the logged parts are now the mean over the ranks, a part a rank lacks counting 0 there
    (as for an object without it within a rank's step). Two gloo processes on the CPU."""
    import json

    parts = [{"loss": 1.0, "mse_fine": 0.2, "hit": 0.5, "depth": 0.4},
             {"loss": 3.0, "mse_fine": 0.4, "hit": 1.0}]
    out = str(tmp_path / "got")
    mp.spawn(_gather_rank, args=(2, _free_port(), parts, out), nprocs=2, join=True)
    for rank in range(2):
        got = json.loads(open(f"{out}.{rank}").read())
        assert got == pytest.approx({"loss": 2.0, "mse_fine": 0.3, "hit": 0.75, "depth": 0.2})


# ------------------------------------------------------------------------------------------- Sem2NeRF's train record

TINY_S2N = (("hidden", 16), ("n_layers", 2), ("encoder_hidden", 32), ("vgg_layers", 4), ("n_coarse", 6),
            ("n_fine", 2), ("style_mean_samples", 200), ("z_dim", 8), ("mapping_hidden", 16))


@pytest.fixture(scope="module")
def masked_data(tmp_path_factory):
    from blender_mrvm.training.synthetic import make_sphere_dataset

    return make_sphere_dataset(tmp_path_factory.mktemp("s2n") / "d", n_objects=2, n_views=4, resolution=16)


def _s2n(data, out, **kw):
    from blender_mrvm.training import sem2nerf as T

    base = dict(data=str(data), out_dir=str(out), preset="fast", model_overrides=TINY_S2N, iterations=1,
                objects_per_step=1, patch_size=4, lpips_weight=0.0, checkpoint_every=1, log_every=1, threads=1)
    return T.train_config(**{**base, **kw})


def _meta(run):
    from blender_mrvm.models.checkpoint_files import MODEL_FILE, find_checkpoint, read_header_meta

    return read_header_meta(find_checkpoint(run / "checkpoints") / MODEL_FILE)


def test_a_sem2nerf_fine_tune_whose_config_json_is_lost_resumes_with_its_init(masked_data, tmp_path):
    """Sem2NeRF checkpoints had recorded four train settings under `train`, not the whole record under
    `train_config` as the other kinds' do: with the run's config.json lost, the resume of a fine-tune with the
    --init it began from was refused ('began from a random initialisation'). A checkpoint of before (only `train`)
    still resumes without --init."""
    import json

    from blender_mrvm.errors import InputError
    from blender_mrvm.progress import run_to_end
    from blender_mrvm.training import sem2nerf as T

    run_to_end(T.train(_s2n(masked_data, tmp_path / "old")))
    ft = tmp_path / "ft"
    cfg = _s2n(masked_data, ft, init_checkpoint=str(tmp_path / "old"))
    run_to_end(T.train(cfg))
    written = json.loads((ft / "config.json").read_text())["train"]
    (ft / "config.json").unlink()
    s = run_to_end(T.train(T.train_config(**{**cfg.__dict__, "iterations": 2})))  # the same --init goes on
    assert s["step"] == 2 and json.loads((ft / "config.json").read_text())["train"]["init_checkpoint"] == str(
        tmp_path / "old")
    meta = _meta(ft)
    assert json.loads(meta["train_config"]) == {**written, "iterations": 2}  # config.json's record
    assert json.loads(meta["train"])["iterations"] == 2  # the record of before is kept

    # a checkpoint written before (no train_config) resumes without --init as it did; with it, as it did, the
    # resume is refused: such a checkpoint does not record the --init
    _as_written_before(ft)
    s = run_to_end(T.train(T.train_config(**{**cfg.__dict__, "init_checkpoint": "", "iterations": 3})))
    assert s["step"] == 3
    _as_written_before(ft)
    with pytest.raises(InputError, match="began from a random initialisation"):
        run_to_end(T.train(T.train_config(**{**cfg.__dict__, "iterations": 4})))


def _as_written_before(run):
    """The run's newest checkpoint as Sem2NeRF wrote it before `train_config`, and its config.json lost."""
    from safetensors.torch import load_file, save_file

    from blender_mrvm.models.checkpoint_files import MODEL_FILE, find_checkpoint

    model_file = find_checkpoint(run / "checkpoints") / MODEL_FILE
    meta = {k: v for k, v in _meta(run).items() if k != "train_config"}
    save_file(load_file(str(model_file)), str(model_file), metadata=meta)
    (run / "config.json").unlink()


# ------------------------------------------------------------------------------------------- GPNR on rooms

def _rooms(scenes):
    """The sphere objects as rooms: a scene background and a box that holds the cameras (as a room's does)."""
    from dataclasses import replace

    import numpy as np

    out = []
    for s in scenes:
        r = float(np.abs(np.asarray(s.c2w)[:, :3, 3]).max()) * 1.5
        out.append(replace(s, background="scene", bbox=(np.full(3, -r), np.full(3, r))))
    return out


def test_a_room_fine_tune_of_a_linear_gpnr_model_warns_about_its_depth_spacing(tmp_path, capsys):
    """`train --init <object gpnr>` on rooms kept the checkpoint's depth_spacing 'linear' silently, where room models
    use 'auto' (0.5-0.8 dB better on held-out rooms, docs/gpnr_rooms.md). A new run with cameras inside the box
    now says so in one warning line naming the setting and how to change it; 'auto', objects seen from outside
    their box, and a resume (which keeps the run's model) are not told."""
    from dataclasses import replace

    from blender_mrvm.datasets.loaders import load_dataset
    from blender_mrvm.models import registry
    from blender_mrvm.progress import run_to_end
    from blender_mrvm.training import checkpoint as ckpt
    from blender_mrvm.training.config import TrainConfig
    from blender_mrvm.training.synthetic import make_sphere_dataset
    from blender_mrvm.training.trainer import train

    root = make_sphere_dataset(tmp_path / "d", n_objects=2, n_views=5, resolution=16, seed=1, data_passes=False)
    objects = load_dataset(root, "train")
    rooms = _rooms(objects)
    own = registry.build_config("gpnr", "fast", {"n_samples": 8, "d_model": 16, "n_heads": 2, "patch_dim": 8,
                                                 "depth_spacing": "linear"})
    ckpt.save_checkpoint(tmp_path / "object_model", 1, registry.build_model(own, load_pretrained=False), own, None)
    base = TrainConfig(data=str(root), out_dir=str(tmp_path / "ft"), init_checkpoint=str(tmp_path / "object_model"),
                       iterations=1, objects_per_step=1, rays_per_object=16, max_ref_views=2, lr_warmup=0,
                       ckpt_every=1, threads=1, opacity_weight=0.0)

    def warned(mcfg, tcfg, scenes):
        capsys.readouterr()
        run_to_end(train(mcfg, tcfg, scenes=scenes))
        return [x for x in capsys.readouterr().err.splitlines() if "depth_spacing" in x]

    lines = warned(own, base, rooms)
    assert len(lines) == 1 and lines[0].startswith("warning: gpnr depth_spacing is 'linear' (kept from --init ")
    n = sum(len(s.c2w) for s in rooms)
    assert f"{n} of {n} training views have their camera inside the box" in lines[0]
    assert '{"model": {"overrides": {"depth_spacing": "auto"}}}' in lines[0]
    assert warned(own, replace(base, iterations=2), rooms) == []  # a resume keeps the run's model
    auto = replace(own, depth_spacing="auto")
    assert warned(auto, replace(base, out_dir=str(tmp_path / "auto")), rooms) == []
    assert warned(own, replace(base, out_dir=str(tmp_path / "objects")), objects) == []  # cameras outside the box
