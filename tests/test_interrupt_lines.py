"""The line Ctrl-C ends a command with says what that command kept, and it is true.

It had said "finished work is kept" for every command: `eval` and `synthesize`, which write only when they finish,
had kept nothing, and the commands that resume did not say that the same command goes on. Each command now has its
clause (``cli.INTERRUPTED``); here the ones that write at the end are interrupted mid-work and their output folder
is checked to be as it was, and the ones whose clause depends on what is on disk are checked both ways."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from blender_mrvm import cli, progress
from blender_mrvm.cli import main
from blender_mrvm.training.synthetic import make_sphere_dataset

from test_synthesize import tiny_checkpoint

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    root = tmp_path_factory.mktemp("interrupt")
    data = make_sphere_dataset(root / "data", n_objects=2, n_views=4, resolution=16, seed=3)
    return root, data, tiny_checkpoint(root / "run")


def _interrupt_after(monkeypatch, events: int) -> list[int]:
    """``run_with_tqdm`` takes ``events`` progress events of the command's work, then the user presses Ctrl-C."""
    seen: list[int] = []

    def interrupted(gen, *args, **kwargs):
        for _ in gen:
            seen.append(1)
            if len(seen) >= events:
                gen.close()
                raise KeyboardInterrupt
        raise AssertionError("the work ended before it could be interrupted")

    monkeypatch.setattr(progress, "run_with_tqdm", interrupted)
    return seen


def _error_lines(capsys) -> list[str]:
    return [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]


def test_every_command_says_what_ctrl_c_keeps():
    """A command added later must decide what its Ctrl-C line says (the two set-up commands say the bare line)."""
    assert set(cli.COMMANDS) - set(cli.INTERRUPTED) == {"build-extension", "fetch-weights"}


def test_eval_interrupted_says_nothing_was_written_and_an_earlier_result_is_as_it_was(small, monkeypatch, capsys):
    root, data, ck = small
    out = root / "eval_out"
    args = ["eval", "--checkpoint", str(ck), "--data", str(data), "--input-views", "0,1", "--no-lpips",
            "--threads", "1", "--device", "cpu", "--out", str(out)]
    assert main(args) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert "eval.json" in before
    capsys.readouterr()
    seen = _interrupt_after(monkeypatch, 1)
    assert main(args + ["--force"]) == 130
    assert seen and _error_lines(capsys) == [f"error: interrupted; nothing was written ({out} is as it was)"]
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before


def test_synthesize_interrupted_writes_nothing_and_says_so(small, monkeypatch, capsys):
    root, data, ck = small
    out = root / "syn_out"
    obj = data / "spheres" / "obj000"
    seen = _interrupt_after(monkeypatch, 1)
    assert main(["synthesize", "--references", str(obj), "--views", "0,1", "--orbit", "4", "--checkpoint", str(ck),
                 "--out", str(out), "--device", "cpu", "--threads", "1"]) == 130
    assert seen and _error_lines(capsys) == [f"error: interrupted; nothing was written ({out} is as it was)"]
    assert not out.exists() or not any(out.rglob("*.png"))


def test_bench_line_names_the_rows_it_kept_only_when_there_are_some(tmp_path):
    from blender_mrvm.bench import model

    parser = cli.build_parser()
    args = parser.parse_args(["bench", "model", "--out", str(tmp_path)])
    assert cli.interrupted_keeps(args) == "nothing was written"
    (tmp_path / model.RESULTS[0]).write_text("preset,seconds\n")
    assert cli.interrupted_keeps(args) == f"the figures measured so far are in {tmp_path / model.RESULTS[0]}"


def test_recover_poses_line_says_to_drop_force_to_go_on(tmp_path):
    parser = cli.build_parser()
    base = ["recover-poses", "--images", str(tmp_path), "--out", str(tmp_path / "o")]
    colmap = tmp_path / "o" / "colmap"
    assert cli.interrupted_keeps(parser.parse_args(base)) == (
        f"the stages finished so far are kept in {colmap}; the same command goes on from them")
    assert cli.interrupted_keeps(parser.parse_args(base + ["--force"])).endswith(
        "the same command without --force goes on from them")


def test_torchrun_and_unknown_commands_keep_their_lines(tmp_path):
    parser = cli.build_parser()
    args = parser.parse_args(["fetch-weights"])
    assert cli.interrupted_keeps(args) == ""
    assert "under torchrun" in cli.interrupted_keeps(parser.parse_args(["train", "--data", str(tmp_path)]), world=2)
