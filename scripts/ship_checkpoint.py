"""Ship a trained checkpoint with the add-on: copy its model file into ``blender_mrvm/assets/checkpoints/``
and write the sidecar the tests and RECIPE.md read (any model kind).

    python scripts/ship_checkpoint.py RUN_OR_CHECKPOINT STEM [--command "python -m blender_mrvm ..."]... [--force]

``RUN_OR_CHECKPOINT``: a run folder (its latest checkpoint), a checkpoint folder or a model file.
``STEM``: the shipped name (``pretrained.SHIPPED``, ``SHIPPED_NAMED`` or ``SEM2NERF_NAME``). The sidecar
``STEM.json`` holds ``model`` (the kind and the exact config stored in the model file), ``train`` (the run's
training config: ``config.json``'s ``train`` section, or the model file's ``train_config``), ``step``, the
sha256 of the model file, and every ``--command`` in order (the stages that made it), so the recipe does
not live only in a scratch folder. A shipped model of that name is replaced only with ``--force``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    from blender_mrvm.models.checkpoint_files import checked_header
    from blender_mrvm.models.pretrained import ASSET_DIR

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("stem")
    ap.add_argument("--command", action="append", default=[], help="a command of the recipe (repeatable, in order)")
    ap.add_argument("--force", action="store_true", help="replace a shipped model of that name")
    ap.add_argument("--fp16", action="store_true", help="store the weights in fp16 (half the bytes)")
    a = ap.parse_args(argv)
    dst = ASSET_DIR / f"{a.stem}.safetensors"
    if dst.exists() and not a.force:
        print(f"error: {dst} is already shipped; pass --force to replace it", file=sys.stderr)
        return 2
    model_file, meta = checked_header(a.checkpoint)
    run_cfg_file = next((p / "config.json" for p in model_file.parents if (p / "config.json").is_file()), None)
    run_cfg = json.loads(run_cfg_file.read_text()) if run_cfg_file else {}
    train = run_cfg.get("train") or json.loads(meta.get("train_config", "{}"))
    side = {"model": {"kind": meta["model_kind"], "config": json.loads(meta["model_config"])}, "train": train,
            "step": int(meta["step"]), **{k: v for k, v in run_cfg.items() if k not in ("model", "train")},
            "commands": a.command}
    if a.fp16:
        from blender_mrvm.training.checkpoint import half_copy

        half_copy(model_file, dst)
        side["fp16_of"] = str(model_file)
    else:
        shutil.copyfile(model_file, dst)
    side["sha256"] = hashlib.sha256(dst.read_bytes()).hexdigest()  # of the file shipped
    (ASSET_DIR / f"{a.stem}.json").write_text(json.dumps(side, indent=2) + "\n")
    print(f"shipped {model_file} -> {dst} ({dst.stat().st_size / 1e6:.2f} MB, step {side['step']}, "
          f"sha256 {side['sha256'][:12]}...)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
