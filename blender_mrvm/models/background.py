"""What a model's images sit on: one rule for training, evaluation and synthesis (bpy-free, torch-free).

A dataset says what its views show (``meta.json`` ``"background"``): an object on white (the default) or a
whole scene (``"scene"``: captures, rooms, recovered photos). The data decides, never a preset:

- training: the model is configured for its data (``white_background`` = the data is on white) before it is
  built, so the checkpoint records it; on scene data, rays that miss the box are not scored (nothing
  beyond the box is the model's to say), on white data they are scored as white as before;
- evaluation and synthesis: a model whose colour is a blend of reference pixels (GPNR: the background only
  fills rays no reference sees and rays outside the box) follows the data it is given; a model that
  composites a volume over its background (NeRFormer, Sem2NeRF) keeps the background it was trained on,
  and a mismatch (an object-on-white model asked for a scene, or the reverse) is reported in one line
  (stderr and the report), never silently.
"""

from __future__ import annotations

from dataclasses import is_dataclass, replace
from typing import Any, Iterable

from ..errors import InputError

WHITE = "white"
SCENE = "scene"


def of_meta(meta: dict) -> str:
    """The background a dataset's ``meta.json`` declares: 'scene' or 'white' (the default)."""
    return SCENE if str((meta or {}).get("background", "")).strip().lower() == SCENE else WHITE


def of_scenes(scenes: Iterable[Any]) -> str:
    """The one background of a list of loaded objects (``ObjectScene.background``); InputError when they mix."""
    kinds: dict[str, str] = {}
    for s in scenes:
        kinds.setdefault(SCENE if getattr(s, "background", WHITE) == SCENE else WHITE,
                         f"{getattr(s, 'category', '?')}/{getattr(s, 'name', '?')}")
    if len(kinds) > 1:
        raise InputError(f"the dataset mixes objects on white (e.g. {kinds[WHITE]}) and whole scenes "
                         f"(background: scene, e.g. {kinds[SCENE]}); train or evaluate them separately")
    return next(iter(kinds), WHITE)


def config_white(cfg: Any) -> bool | None:
    """A model config's ``white_background`` (top level or in its ``render`` section); None if it has none."""
    if hasattr(cfg, "white_background"):
        return bool(cfg.white_background)
    r = getattr(cfg, "render", None)
    if r is not None and hasattr(r, "white_background"):
        return bool(r.white_background)
    return None


def with_white(cfg: Any, white: bool) -> Any:
    """``cfg`` with ``white_background`` set (a frozen dataclass: a new one)."""
    if hasattr(cfg, "white_background"):
        return replace(cfg, white_background=bool(white))
    r = getattr(cfg, "render", None)
    if r is not None and is_dataclass(r) and hasattr(r, "white_background"):
        return replace(cfg, render=replace(r, white_background=bool(white)))
    return cfg


def for_training(cfg: Any, background: str) -> tuple[Any, str | None]:
    """(config for training on data with ``background``, a note when it changed)."""
    want = background != SCENE
    have = config_white(cfg)
    if have is None or have == want:
        return cfg, None
    what = "whole scenes (background: scene)" if not want else "objects on white"
    return with_white(cfg, want), (f"the data shows {what}: the model is trained with white_background={want} "
                                   f"(its config said {have})")


def blends_references(model: Any) -> bool:
    """True for models whose colour is a blend of reference pixels (the background only fills rays no
    reference sees), False for models that composite a volume over their background."""
    return bool(getattr(model, "blends_references", False))


def for_rendering(model: Any, background: str) -> str | None:
    """Set up ``model`` (in place) to render data with ``background``; returns a one-line note when the
    model was trained for the other background (None when they agree)."""
    want = background != SCENE
    have = config_white(model.cfg)
    if have is None or have == want:
        return None
    data = "whole scenes (background: scene)" if not want else "objects on white"
    trained = "objects on white" if have else "whole scenes"
    if blends_references(model):
        model.cfg = with_white(model.cfg, want)
        return (f"the data shows {data}; this {model.kind} model (set up for {trained}) blends reference pixels, "
                f"so it renders with white_background={want} (the fill of rays no reference sees)")
    return (f"this {model.kind} model composites on {'white' if have else 'black'} (trained on {trained}) but the "
            f"data shows {data}: it cannot render what lies outside its object, so expect poor images and scores")
