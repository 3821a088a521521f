"""Copy a checkpoint with inference-only model settings changed (the weights and training record unchanged).

    python scripts/set_inference_config.py SRC OUT_RUN key=value [key=value ...]

SRC: any checkpoint form ``load_model`` accepts (run folder, step folder, model file, shipped:<kind>); OUT_RUN:
a new run folder (refused if it exists); it gets ``checkpoints/step_<same step>/model.safetensors`` whose
config has the given fields replaced (values parsed as JSON, else strings) - e.g. GPNR's
``alpha_temperature=0.03 n_samples=48 white_background=false``. The new config must build a model the
same weights load into strictly (a setting that changes an architecture is refused).
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path


def main(argv: list[str]) -> int:
    from blender_mrvm.models import registry
    from blender_mrvm.models.checkpoint_files import model_file_of
    from blender_mrvm.models.pretrained import resolve_checkpoint
    from blender_mrvm.training import checkpoint as ck

    src, out, pairs = argv[0], Path(argv[1]), argv[2:]
    if out.exists():
        raise SystemExit(f"error: {out} exists")
    path = resolve_checkpoint(src)
    model, cfg, meta = ck.load_model(path)
    over = {}
    for p in pairs:
        k, v = p.split("=", 1)
        try:
            over[k] = json.loads(v)
        except json.JSONDecodeError:
            over[k] = v
    new = dataclasses.replace(cfg, **over)
    registry.validate(new)
    fresh = registry.build_model(new, load_pretrained=False)
    fresh.load_state_dict(model.state_dict(), strict=True)
    extra = {k: v for k, v in meta.items() if k not in ("format", "format_version", "step", "model_kind", "model_config")}
    extra["derived_from"] = json.dumps({"checkpoint": str(model_file_of(path)), "changed": over})
    done = ck.save_checkpoint(out, int(meta.get("step", 0)), fresh, new, None, extra)
    print(done / ck.MODEL_FILE)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
