"""A ShapeNet-style object library: one seeded generator per ShapeNet-13 category, with part labels.

``build(category, seed, collection, **params)`` returns one mesh object normalized like ShapeNetCore
v2 (bbox centre at the origin, bbox diagonal 1, z up, front facing -y). Every face carries a global
part label (:data:`PART_LABELS`, 0 = background): an int FACE attribute ``part_id`` and a material
per part whose ``pass_index`` is the label id. Parameters not given are drawn from the seed; the
accepted names and ranges are listed by :func:`parameters`.

Each call creates only datablocks the returned object links (its mesh and its materials, whose
node trees are embedded), so a caller can clean up by diffing ``bpy.data``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._registry import CATEGORIES, GENERATORS, PART_LABELS, PARTS, Param, label_ids, resolve

__all__ = ["CATEGORIES", "PART_LABELS", "PARTS", "build", "labels_of", "parameters", "sample_parameters"]

LABELLED_PROP = "mrvm_part_labels"


def _load_generators() -> None:
    if len(GENERATORS) < len(CATEGORIES):
        from . import electronics, furniture, vehicles  # noqa: F401  (registering imports)


def parameters(category: str) -> tuple[Param, ...]:
    """The named parameters of ``category``'s generator."""
    _load_generators()
    resolve(category, 0, {})  # validates the name
    return GENERATORS[category].params


def sample_parameters(category: str, seed: int, **params: Any) -> dict[str, Any]:
    """The full parameter set ``build`` would use (validated); needs no scene."""
    _load_generators()
    p, _ = resolve(category, seed, params)
    return dict(p)


def build(category: str, seed: int, collection, **params: Any):
    """One labelled, ShapeNet-normalized mesh object of ``category`` linked into ``collection``.

    Raises :class:`~blender_mrvm.errors.InputError` for an unknown category, an unknown or invalid
    parameter, or a seed that is not a non-negative integer.
    """
    import bpy

    from ._materials import make_material
    from ._mesh import PartMesh

    _load_generators()
    p, seed = resolve(category, seed, params)
    ci = CATEGORIES.index(category)
    rng = np.random.default_rng([seed, ci, 1])
    ids = label_ids(category)
    m = PartMesh(ids)
    kinds = GENERATORS[category].fn(p, rng, m)
    name = f"{category}_{seed:06d}"
    mesh, labels = m.to_mesh(name)

    present = sorted(set(int(x) for x in np.unique(labels)))
    names = {v: k for k, v in ids.items()}
    mat_rng = np.random.default_rng([seed, ci, 2])
    slot = {}
    for lab in present:
        part = names[lab]
        spec = kinds.get(part, "plastic")
        kind, color = (spec, None) if isinstance(spec, str) else spec
        mat = make_material(f"{name}_{part}", kind, mat_rng, lab, color)
        slot[lab] = len(mesh.materials)
        mesh.materials.append(mat)
    mesh.polygons.foreach_set("material_index", np.array([slot[int(x)] for x in labels], dtype=np.int32))

    obj = bpy.data.objects.new(name, mesh)
    obj[LABELLED_PROP] = True
    obj["mrvm_source"] = f"procedural:{category}:{seed}"
    obj["mrvm_params"] = repr(dict(p))
    collection.objects.link(obj)
    return obj


def labels_of(obj) -> dict[int, str]:
    """The part labels present on an object built by :func:`build` (id -> "category/part")."""
    attr = obj.data.attributes.get("part_id") if getattr(obj, "data", None) is not None else None
    if attr is None or attr.domain != "FACE":
        return {}
    vals = np.zeros(len(obj.data.polygons), dtype=np.int32)
    attr.data.foreach_get("value", vals)
    return {int(i): PART_LABELS.get(int(i), f"unknown/{int(i)}") for i in np.unique(vals) if i != 0}
