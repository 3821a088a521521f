#!/usr/bin/env python3
"""Average the weights of models fine-tuned from one starting point (a "model soup"; see
``training.checkpoint.average_model_files``) into one model file, then score it with ``eval`` like any other.

    .venv/bin/python scripts/average_checkpoints.py data/runs/a data/runs/b --out data/runs/soup.safetensors

Each argument is a run folder, checkpoint folder or model file (the latest checkpoint of a run)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from blender_mrvm.errors import InputError  # noqa: E402
from blender_mrvm.models.checkpoint_files import model_file_of  # noqa: E402
from blender_mrvm.training.checkpoint import average_model_files  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("models", nargs="+", help="run folders, checkpoint folders or model files (two or more)")
    p.add_argument("--out", required=True, type=Path, help="the averaged model file (.safetensors)")
    args = p.parse_args(argv)
    try:
        files = [model_file_of(Path(m)) for m in args.models]
        print(average_model_files(files, args.out))
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
