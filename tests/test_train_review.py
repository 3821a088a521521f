"""`train` as a researcher runs it (session review): run-config model sections that were read as something else
than they said, reference counts the trained model refuses, and the checkpoint-keeping order past step 10^7.

Each case was reproduced on the code before its fix: a misspelt model-section key or a preset beside a full config
trained the default model with exit 0; ``overrides`` beside a full config were dropped; ``"overrides": 5`` or
``{"nerformer": 5}`` raised AttributeError; ``train.max_ref_views`` 14 on a model of 10 trained, and the checkpoint
then refused 12 references; the ten-millionth step's save pruned the newer checkpoints and kept the old ones.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from blender_mrvm.cli import main
from blender_mrvm.errors import InputError
from blender_mrvm.models.config import PRESETS, to_dict
from blender_mrvm.training.config import load_run_config

torch.set_num_threads(1)


def _config(tmp_path: Path, model: dict, **train) -> Path:
    p = tmp_path / "run.json"
    p.write_text(json.dumps({"model": model, "train": {"out_dir": str(tmp_path / "run"), "iterations": 2, **train}}))
    return p


@pytest.mark.parametrize("model, words", [
    ({"preset": "fast", "overides": {"nerformer": {"d_model": 48}}}, "['overides']"),
    ({"prest": "fast"}, "['prest']"),
    ({"preset": "fast", "config": {}}, "both a preset ('fast') and a full config"),
])
def test_model_section_read_as_written(tmp_path, model, words):
    """A model section with a key ``train`` does not read, or a preset beside a full config, is refused in one line:
    before, the key (the preset) was dropped and the default model (balanced) trained, exit 0."""
    with pytest.raises(InputError) as e:
        load_run_config(_config(tmp_path, model))
    assert words in str(e.value) and "\n" not in str(e.value)


def test_overrides_beside_a_full_config_apply(tmp_path):
    """A run's config.json (a full model config) with overrides added: they apply (they were dropped without a word)
    and the result is validated."""
    full = {"kind": "nerformer_mrvm", "config": to_dict(PRESETS["fast"])}
    mcfg, _ = load_run_config(_config(tmp_path, {**full, "overrides": {"nerformer": {"n_layers": 2}}}))
    assert mcfg.nerformer.n_layers == 2 and mcfg.encoder == PRESETS["fast"].encoder
    with pytest.raises(InputError, match="divisible"):
        load_run_config(_config(tmp_path, {**full, "overrides": {"nerformer": {"n_heads": 5}}}))


@pytest.mark.parametrize("overrides", [5, [1], {"nerformer": 5}, {"encoder": "vgg16"}])
def test_overrides_of_the_wrong_shape_one_error_line(tmp_path, capsys, overrides):
    """``overrides`` that are not a mapping, or a section given a value: one ``error:`` line and exit 2 (was an
    AttributeError traceback, exit 1)."""
    cfg = _config(tmp_path, {"preset": "fast", "overrides": overrides}, data=str(tmp_path / "data"))
    assert main(["train", "--config", str(cfg)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:"), err
    assert not (tmp_path / "run").exists()


def test_train_reference_counts_within_the_model(tmp_path):
    """``train.max_ref_views`` above the model's ``max_ref_views`` (or ``min_ref_views`` below the model's) is refused
    before anything runs: such a run trained at 12-14 references a model that then refused ``--nearest 12``."""
    with pytest.raises(InputError, match=r"train.max_ref_views \(14\) is above the model's max_ref_views \(10\)"):
        load_run_config(_config(tmp_path, {"preset": "fast"}, min_ref_views=12, max_ref_views=14))
    mcfg, tcfg = load_run_config(_config(tmp_path, {"preset": "fast", "overrides": {"max_ref_views": 14}},
                                         min_ref_views=12, max_ref_views=14))
    assert mcfg.max_ref_views == 14 and tcfg.max_ref_views == 14
    with pytest.raises(InputError, match=r"train.min_ref_views \(1\) is below the model's min_ref_views \(2\)"):
        load_run_config(_config(tmp_path, {"kind": "gpnr", "preset": "fast", "overrides": {"min_ref_views": 2}}))
    load_run_config(_config(tmp_path, {"kind": "gpnr", "preset": "fast", "overrides": {"min_ref_views": 2}},
                            min_ref_views=2, max_ref_views=4))


def test_keep_checkpoints_by_step_past_ten_million(tmp_path):
    """The newest ``keep`` checkpoints by step survive a save: by name, ``step_10000000`` sorted before
    ``step_9999000``, and every save from then on pruned the newer ones and kept the old."""
    from blender_mrvm.training.checkpoint import save_checkpoint

    model, cfg = torch.nn.Linear(2, 2), PRESETS["fast"]
    for step in (9_998_000, 9_999_000, 10_000_000, 10_001_000, 10_002_000):
        save_checkpoint(tmp_path, step, model, cfg, None, keep=2, kind="nerformer_mrvm")
    left = sorted(p.name for p in (tmp_path / "checkpoints").glob("step_*"))
    assert left == ["step_10001000", "step_10002000"], left
