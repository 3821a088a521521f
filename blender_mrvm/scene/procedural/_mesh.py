"""A labelled mesh builder for the procedural categories.

Every part is made from a bmesh primitive (cube, cone/cylinder, UV sphere, an extruded 2D profile)
or a swept/lofted surface, bevelled where it has hard edges, and stored as plain vertex/face arrays
together with its global part label. :meth:`PartMesh.to_mesh` writes one ``bpy`` mesh with an int
FACE attribute ``part_id`` and ``material_index`` set from the labels.

Coordinates: world z up, the object's front faces -y (ShapeNetCore v2 as imported into Blender).
"""

from __future__ import annotations

import math
from typing import Sequence

import bmesh
import bpy
import numpy as np
from mathutils import Matrix, Vector


def _rot_to(axis) -> Matrix:
    """Rotation taking +z onto ``axis``."""
    a = Vector(axis).normalized()
    return Vector((0.0, 0.0, 1.0)).rotation_difference(a).to_matrix().to_4x4()


def _euler(rot) -> Matrix:
    if rot is None:
        return Matrix.Identity(4)
    from mathutils import Euler
    return Euler(rot, "XYZ").to_matrix().to_4x4()


def _frame_along(d: np.ndarray, prev_n: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to ``d`` (parallel transport from ``prev_n`` when given)."""
    if prev_n is None:
        ref = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        n = np.cross(d, ref)
    else:
        n = prev_n - d * np.dot(prev_n, d)
        if np.linalg.norm(n) < 1e-9:
            ref = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
            n = np.cross(d, ref)
    n = n / np.linalg.norm(n)
    b = np.cross(d, n)
    return n, b


class PartMesh:
    """Accumulates labelled parts; each ``add_*`` returns nothing and records one label per face."""

    def __init__(self, label_ids: dict[str, int] | None = None) -> None:
        self.label_ids = dict(label_ids or {})
        self._verts: list[np.ndarray] = []
        self._faces: list[list[int]] = []
        self._labels: list[int] = []
        self._smooth: list[bool] = []
        self._nv = 0

    # ---- low level -------------------------------------------------------------------------

    def add_arrays(self, label: int, verts, faces: Sequence[Sequence[int]], smooth: bool = False) -> None:
        verts = np.asarray(verts, dtype=np.float64).reshape(-1, 3)
        off = self._nv
        self._verts.append(verts)
        self._faces.extend([[i + off for i in f] for f in faces])
        if isinstance(label, (str, int, np.integer)):
            self._labels.extend([self.lid(label)] * len(faces))
        else:
            if len(label) != len(faces):
                raise ValueError("one label per face expected")
            self._labels.extend(self.lid(x) for x in label)
        self._smooth.extend([smooth] * len(faces))
        self._nv += len(verts)

    def add_bmesh(self, label: int, bm: bmesh.types.BMesh, smooth: bool = False) -> None:
        bm.verts.index_update()
        verts = np.array([v.co[:] for v in bm.verts], dtype=np.float64).reshape(-1, 3)
        faces = [[v.index for v in f.verts] for f in bm.faces]
        bm.free()
        self.add_arrays(label, verts, faces, smooth)

    def lid(self, label) -> int:
        """Global id of a part name (or an id passed through)."""
        return self.label_ids[label] if isinstance(label, str) else int(label)

    @staticmethod
    def _bevel(bm: bmesh.types.BMesh, width: float, segments: int = 2, edges=None) -> None:
        if width <= 0:
            return
        edges = list(bm.edges) if edges is None else edges
        bmesh.ops.bevel(bm, geom=edges, offset=width, offset_type="OFFSET", segments=segments,
                        profile=0.5, affect="EDGES", clamp_overlap=True)
        # clamped bevels on short edges can leave zero-length edges / zero-area faces: remove them
        bmesh.ops.dissolve_degenerate(bm, dist=width * 0.02, edges=bm.edges[:])

    # ---- primitives ------------------------------------------------------------------------

    def box(self, label: int, size, center=(0, 0, 0), bevel: float = 0.0, rot=None, segments: int = 2) -> None:
        """An axis-aligned box of ``size`` (sx, sy, sz) around ``center``, edges bevelled by ``bevel``."""
        sx, sy, sz = (float(s) for s in size)
        bm = bmesh.new()
        bmesh.ops.create_cube(bm, size=1.0)
        bmesh.ops.scale(bm, vec=(sx, sy, sz), verts=bm.verts)
        self._bevel(bm, min(bevel, 0.45 * min(sx, sy, sz)), segments)
        bmesh.ops.transform(bm, matrix=Matrix.Translation(Vector(center)) @ _euler(rot), verts=bm.verts)
        self.add_bmesh(label, bm)

    def cylinder(self, label: int, radius: float, depth: float, center=(0, 0, 0), axis=(0, 0, 1),
                 radius2: float | None = None, segments: int = 16, bevel: float = 0.0, smooth: bool = True) -> None:
        """A capped cylinder (or truncated cone with top radius ``radius2``) along ``axis``."""
        r2 = radius if radius2 is None else radius2
        bm = bmesh.new()
        bmesh.ops.create_cone(bm, cap_ends=True, cap_tris=False, segments=segments, radius1=radius,
                              radius2=max(r2, 0.0), depth=depth)
        if bevel > 0:
            caps = [e for e in bm.edges if len(e.link_faces) == 2
                    and any(len(f.verts) > 4 for f in e.link_faces)]
            self._bevel(bm, min(bevel, 0.45 * depth, 0.45 * max(min(radius, r2 if r2 > 0 else radius), 1e-6)),
                        2, caps)
        bmesh.ops.transform(bm, matrix=Matrix.Translation(Vector(center)) @ _rot_to(axis), verts=bm.verts)
        self.add_bmesh(label, bm, smooth)

    def cylinder_between(self, label: int, p0, p1, radius: float, radius2: float | None = None,
                         segments: int = 12, bevel: float = 0.0) -> None:
        p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
        d = p1 - p0
        self.cylinder(label, radius, float(np.linalg.norm(d)), center=(p0 + p1) / 2, axis=d,
                      radius2=radius2, segments=segments, bevel=bevel)

    def sphere(self, label: int, radius: float, center=(0, 0, 0), scale=(1, 1, 1), segments: int = 16,
               rings: int = 8, rot=None) -> None:
        bm = bmesh.new()
        bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=rings, radius=radius)
        bmesh.ops.scale(bm, vec=scale, verts=bm.verts)
        bmesh.ops.transform(bm, matrix=Matrix.Translation(Vector(center)) @ _euler(rot), verts=bm.verts)
        self.add_bmesh(label, bm, True)

    def torus(self, label: int, major: float, minor: float, center=(0, 0, 0), axis=(0, 0, 1),
              segments: int = 20, sides: int = 8) -> None:
        u = np.linspace(0, 2 * np.pi, segments, endpoint=False)
        v = np.linspace(0, 2 * np.pi, sides, endpoint=False)
        uu, vv = np.meshgrid(u, v, indexing="ij")
        x = (major + minor * np.cos(vv)) * np.cos(uu)
        y = (major + minor * np.cos(vv)) * np.sin(uu)
        z = minor * np.sin(vv)
        pts = np.stack([x, y, z], -1).reshape(-1, 3)
        m = np.array(_rot_to(axis).to_3x3())
        pts = pts @ m.T + np.asarray(center, float)
        faces = []
        for i in range(segments):
            for j in range(sides):
                i2, j2 = (i + 1) % segments, (j + 1) % sides
                faces.append([i * sides + j, i2 * sides + j, i2 * sides + j2, i * sides + j2])
        self.add_arrays(label, pts, faces, smooth=True)

    def profile(self, label: int, pts2d, thickness: float, plane: str = "yz", offset: float = 0.0,
                bevel: float = 0.0, segments: int = 2) -> None:
        """A 2D polygon (counter-clockwise) in ``plane`` extruded symmetrically by ``thickness``.

        ``plane`` "yz": the profile's (u, v) are (y, z), extruded along x and centred at x=``offset``;
        "xz": (x, z) extruded along y; "xy": (x, y) extruded along z.
        """
        pts2d = np.asarray(pts2d, float)
        bm = bmesh.new()
        vs = [bm.verts.new((u, v, -thickness / 2)) for u, v in pts2d]
        f = bm.faces.new(vs)
        f.normal_update()
        if f.normal.z > 0:
            f.normal_flip()
        ret = bmesh.ops.extrude_face_region(bm, geom=[f])
        top = [e for e in ret["geom"] if isinstance(e, bmesh.types.BMVert)]
        bmesh.ops.translate(bm, vec=(0, 0, thickness), verts=top)
        bmesh.ops.recalc_face_normals(bm, faces=bm.faces)
        if bevel > 0:
            self._bevel(bm, min(bevel, 0.45 * thickness), segments)
        if plane == "yz":
            m = Matrix(((0, 0, 1, offset), (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 0, 1)))
        elif plane == "xz":
            m = Matrix(((1, 0, 0, 0), (0, 0, 1, offset), (0, 1, 0, 0), (0, 0, 0, 1)))
        else:
            m = Matrix.Translation((0, 0, offset))
        bmesh.ops.transform(bm, matrix=m, verts=bm.verts)
        # keep outward normals after the (possibly mirroring) axis permutation
        if m.to_3x3().determinant() < 0:
            bmesh.ops.reverse_faces(bm, faces=bm.faces)
        self.add_bmesh(label, bm)

    def tube(self, label: int, path, radius, segments: int = 10, cap: bool = True) -> None:
        """A circular tube swept along a polyline ``path`` (radius scalar or per point)."""
        path = np.asarray(path, float)
        n = len(path)
        r = np.broadcast_to(np.asarray(radius, float), (n,))
        ang = np.linspace(0, 2 * np.pi, segments, endpoint=False)
        rings = []
        prev = None
        for i in range(n):
            d = path[min(i + 1, n - 1)] - path[max(i - 1, 0)]
            d = d / np.linalg.norm(d)
            nvec, bvec = _frame_along(d, prev)
            prev = nvec
            rings.append(path[i] + r[i] * (np.cos(ang)[:, None] * nvec + np.sin(ang)[:, None] * bvec))
        self.loft(label, rings, cap_start=cap, cap_end=cap)

    def loft(self, label, rings, cap_start: bool = True, cap_end: bool = True, smooth: bool = True,
             tip_start=None, tip_end=None, closed: bool = False) -> None:
        """A surface through closed rings of equal length (each (k, 3)); caps are n-gons, or fans to
        a ``tip`` point when given; ``closed`` joins the last ring back to the first (no caps).
        Faces come ring-gap by ring-gap (gap i, segment j -> face i*k + j), then caps."""
        rings = [np.asarray(r, float) for r in rings]
        k = len(rings[0])
        verts = np.concatenate(rings, 0)
        faces = []
        if closed:
            cap_start = cap_end = False
            tip_start = tip_end = None
            rings = rings + [rings[0]]
        nr = len(rings)
        for i in range(nr - 1):
            i1 = (i + 1) % (nr - 1) if closed else i + 1
            for j in range(k):
                j2 = (j + 1) % k
                faces.append([i * k + j, i * k + j2, i1 * k + j2, i1 * k + j])
        extra = []
        nv = len(verts)
        if tip_start is not None:
            extra.append(np.asarray(tip_start, float))
            faces += [[nv, (j + 1) % k, j] for j in range(k)]
            nv += 1
        elif cap_start:
            faces.append(list(range(k))[::-1])
        last = (nr - 1) * k
        if tip_end is not None:
            extra.append(np.asarray(tip_end, float))
            faces += [[last + j, last + (j + 1) % k, nv] for j in range(k)]
        elif cap_end:
            faces.append([last + j for j in range(k)])
        if extra:
            verts = np.concatenate([verts, np.array(extra)], 0)
        self.add_arrays(label, verts, faces, smooth)

    # ---- output ----------------------------------------------------------------------------

    @property
    def n_faces(self) -> int:
        return len(self._faces)

    def mirrored_x(self, start_face: int) -> None:
        """Duplicate the faces added since ``start_face`` mirrored across x = 0 (winding flipped)."""
        verts = np.concatenate(self._verts, 0)
        faces = self._faces[start_face:]
        used = sorted({i for f in faces for i in f})
        remap = {old: new for new, old in enumerate(used)}
        v = verts[used].copy()
        v[:, 0] *= -1
        new_faces = [[remap[i] for i in f][::-1] for f in faces]
        labels = self._labels[start_face:]
        smooth = self._smooth[start_face:]
        off = self._nv
        self._verts.append(v)
        self._faces.extend([[i + off for i in f] for f in new_faces])
        self._labels.extend(labels)
        self._smooth.extend(smooth)
        self._nv += len(v)

    def arrays(self) -> tuple[np.ndarray, list[list[int]], np.ndarray, np.ndarray]:
        return (np.concatenate(self._verts, 0), self._faces, np.asarray(self._labels, np.int32),
                np.asarray(self._smooth, bool))

    def to_mesh(self, name: str, normalize: bool = True) -> tuple[bpy.types.Mesh, np.ndarray]:
        """A new mesh (ShapeNet-normalized when ``normalize``); returns it and the face labels."""
        verts, faces, labels, smooth = self.arrays()
        if normalize:
            lo, hi = verts.min(0), verts.max(0)
            verts = (verts - (lo + hi) / 2) / float(np.linalg.norm(hi - lo))
        me = bpy.data.meshes.new(name)
        me.vertices.add(len(verts))
        me.vertices.foreach_set("co", verts.astype(np.float32).ravel())
        sizes = np.fromiter((len(f) for f in faces), dtype=np.int32, count=len(faces))
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int32)
        me.loops.add(int(sizes.sum()))
        me.loops.foreach_set("vertex_index", np.fromiter((i for f in faces for i in f), dtype=np.int32))
        me.polygons.add(len(faces))
        me.polygons.foreach_set("loop_start", starts)
        me.polygons.foreach_set("loop_total", sizes)
        me.update(calc_edges=True)
        me.validate(clean_customdata=False)
        if len(me.polygons) != len(faces):
            raise RuntimeError(f"mesh validation removed {len(faces) - len(me.polygons)} faces of {name}")
        # consistent outward normals per connected part (lofts and mirrored blocks come in any winding)
        bm = bmesh.new()
        bm.from_mesh(me)
        bmesh.ops.recalc_face_normals(bm, faces=bm.faces)
        bm.to_mesh(me)
        bm.free()
        me.polygons.foreach_set("use_smooth", np.ones(len(faces), bool))
        me.set_sharp_from_angle(angle=math.radians(40.0))
        attr = me.attributes.new("part_id", "INT", "FACE")
        attr.data.foreach_set("value", labels)
        return me, labels
