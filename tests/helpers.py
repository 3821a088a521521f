"""Test data made here (nothing downloaded): small asymmetric meshes in every supported format."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def asymmetric_mesh():
    """A box with a sphere on one corner and a bar on another: no symmetry hides a flipped axis."""
    import trimesh

    box = trimesh.creation.box(extents=(0.8, 0.5, 0.4))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.22)
    ball.apply_translation((0.35, 0.2, 0.3))
    bar = trimesh.creation.box(extents=(0.15, 0.15, 0.7))
    bar.apply_translation((-0.35, -0.2, 0.3))
    return trimesh.util.concatenate([box, ball, bar])


def write_mesh(path: Path, mesh=None) -> Path:
    mesh = mesh if mesh is not None else asymmetric_mesh()
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(path)
    return path


def depth_consistency(ov, a: int, b: int, occlusion: float = 0.02) -> np.ndarray:
    """Relative z errors of view a's depth unprojected and reprojected into view b.

    B's depth is sampled bilinearly where all four neighbours are foreground. Points that land
    more than ``occlusion`` (relative) behind B's surface are hidden in B and skipped; points in
    front of it are kept, so a wrong pose or depth scale still shows.
    """
    from blender_mrvm.geometry import cameras as C

    da, db = ov.depth(a), ov.depth(b)
    per_view = getattr(ov, "intrinsics_per_view", None) or [ov.intrinsics] * len(ov.indices)
    pts = C.unproject_depth(per_view[a], ov.c2w_opencv[a], da)[da > 0]  # each view with its own intrinsics
    uv, z = C.project(per_view[b].K, C.invert_pose(ov.c2w_opencv[b]), pts)
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5  # pixel-centre convention -> array coordinates
    h, w = db.shape
    ok = (x >= 0) & (x < w - 1) & (y >= 0) & (y < h - 1) & (z > 0)
    x, y, z = x[ok], y[ok], z[ok]
    i, j = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - i, y - j
    q = np.stack([db[j, i], db[j, i + 1], db[j + 1, i], db[j + 1, i + 1]])
    fg = (q > 0).all(axis=0)
    dbv = (q[0] * (1 - fx) * (1 - fy) + q[1] * fx * (1 - fy) + q[2] * (1 - fx) * fy + q[3] * fx * fy)[fg]
    z = z[fg]
    rel = (z - dbv) / dbv
    return np.abs(rel[rel < occlusion])


def _z_up_to_y_up(v: np.ndarray) -> np.ndarray:
    """Blender's Z-up coordinates in a Y-up file's: (x, y, z) -> (x, z, -y)."""
    return np.stack([v[:, 0], v[:, 2], -v[:, 1]], axis=1)


def write_collada(path: Path, up: str = "Z_UP", texture: str | None = None, rgb=(0.8, 0.05, 0.05),
                  edges: bool = False) -> Path:
    """:func:`asymmetric_mesh` as a COLLADA 1.4.1 file (Blender 5 writes none): its vertices in the file's ``up``
    axis (Z_UP or Y_UP), under a node whose matrix (a rotation, a scale and a move) the vertices are stored
    undone by, so only a reader that applies the node's transform and the up axis puts the object where it is.
    A lambert material of colour ``rgb``, or of the image ``texture`` (a file name) through planar UVs. With
    ``edges``, the mesh's first face's edges also as ``<lines>`` beside its triangles, and as a second geometry of
    ``<linestrips>`` only on the same node, as SketchUp draws a model's edges."""
    m = asymmetric_mesh()
    v = np.asarray(m.vertices, dtype=np.float64)
    f = np.asarray(m.faces, dtype=np.int64)
    c, s = np.cos(0.7), np.sin(0.7)
    node = np.array([[c * 2, -s * 2, 0, 0.3], [s * 2, c * 2, 0, -0.2], [0, 0, 2, 0.5], [0, 0, 0, 1]])  # Z-up
    if up == "Y_UP":
        swap = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=np.float64)  # Z-up -> Y-up
        node = swap @ node @ swap.T
        v = _z_up_to_y_up(v)
    local = (np.linalg.inv(node) @ np.c_[v, np.ones(len(v))].T).T[:, :3]
    nums = lambda a: " ".join(f"{x:.9g}" for x in np.asarray(a).ravel())  # noqa: E731
    uv_src = uv_in = bind = img = ""
    diffuse = f"<color>{nums(list(rgb) + [1.0])}</color>"
    if texture is not None:
        uv = (v[:, :2] - v[:, :2].min(0)) / np.ptp(v[:, :2], axis=0)
        uv_src = (f'<source id="uv"><float_array id="uv-a" count="{uv.size}">{nums(uv)}</float_array><technique_common>'
                  f'<accessor source="#uv-a" count="{len(uv)}" stride="2"><param name="S" type="float"/>'
                  '<param name="T" type="float"/></accessor></technique_common></source>')
        uv_in = '<input semantic="TEXCOORD" source="#uv" offset="0" set="0"/>'
        bind = '<bind_vertex_input semantic="UVMap" input_semantic="TEXCOORD" input_set="0"/>'
        img = f'<library_images><image id="tex"><init_from>{texture}</init_from></image></library_images>'
        diffuse = '<texture texture="samp" texcoord="UVMap"/>'
    lines = edge_geo = edge_inst = ""
    if edges:
        a, b, c = f[0]
        lines = (f'<lines count="3"><input semantic="VERTEX" source="#vtx" offset="0"/><p>{a} {b} {b} {c} {c} {a}</p>'
                 '</lines>')
        edge_geo = (f'<geometry id="edges" name="edges"><mesh><source id="epos"><float_array id="epos-a" '
                    f'count="{local.size}">{nums(local)}</float_array><technique_common><accessor source="#epos-a" '
                    f'count="{len(local)}" stride="3"><param name="X" type="float"/><param name="Y" type="float"/>'
                    '<param name="Z" type="float"/></accessor></technique_common></source><vertices id="evtx">'
                    '<input semantic="POSITION" source="#epos"/></vertices><linestrips count="1"><input '
                    f'semantic="VERTEX" source="#evtx" offset="0"/><p>{a} {b} {c} {a}</p></linestrips></mesh>'
                    '</geometry>')
        edge_inst = '<instance_geometry url="#edges"/>'
    params = ('<newparam sid="surf"><surface type="2D"><init_from>tex</init_from></surface></newparam>'
              '<newparam sid="samp"><sampler2D><source>surf</source></sampler2D></newparam>') if texture else ""
    path.write_text(f"""<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
<asset><unit name="meter" meter="1"/><up_axis>{up}</up_axis></asset>
{img}
<library_effects><effect id="fx"><profile_COMMON>{params}<technique sid="common"><lambert><diffuse>{diffuse}</diffuse>
</lambert></technique></profile_COMMON></effect></library_effects>
<library_materials><material id="mat" name="paint"><instance_effect url="#fx"/></material></library_materials>
<library_geometries><geometry id="geo" name="thing"><mesh>
<source id="pos"><float_array id="pos-a" count="{local.size}">{nums(local)}</float_array><technique_common>
<accessor source="#pos-a" count="{len(local)}" stride="3"><param name="X" type="float"/><param name="Y" type="float"/>
<param name="Z" type="float"/></accessor></technique_common></source>{uv_src}
<vertices id="vtx"><input semantic="POSITION" source="#pos"/></vertices>
<triangles material="m" count="{len(f)}"><input semantic="VERTEX" source="#vtx" offset="0"/>{uv_in}<p>{nums(f)}</p>
</triangles>{lines}</mesh></geometry>{edge_geo}</library_geometries>
<library_visual_scenes><visual_scene id="scene"><node id="thing" name="thing"><matrix>{nums(node)}</matrix>
<instance_geometry url="#geo"><bind_material><technique_common><instance_material symbol="m" target="#mat">{bind}
</instance_material></technique_common></bind_material></instance_geometry>{edge_inst}</node></visual_scene>
</library_visual_scenes>
<scene><instance_visual_scene url="#scene"/></scene>
</COLLADA>
""")
    return path


def write_ascii_fbx(path: Path, rgb=(0.8, 0.05, 0.05), up: str = "Y") -> Path:
    """:func:`asymmetric_mesh` as an ASCII FBX 7.3 file (Blender reads binary FBX only): Y-up, as FBX files from
    most tools, or Z-up with -Y forward, as 3ds Max writes them (``up="Z"``), its axes in GlobalSettings; one model,
    one mesh, one material of colour ``rgb``."""
    m = asymmetric_mesh()
    v = np.asarray(m.vertices, dtype=np.float64)
    if up == "Y":
        v = _z_up_to_y_up(v)
    axes = (1, 1, 2, 1) if up == "Y" else (2, 1, 1, -1)  # up axis and sign, front axis and sign
    f = np.asarray(m.faces, dtype=np.int64).copy()
    f[:, 2] = -f[:, 2] - 1  # FBX marks a polygon's last index by its bitwise complement
    nums = lambda a: ",".join(f"{x:.9g}" for x in np.asarray(a).ravel())  # noqa: E731
    r, g, b = rgb
    path.write_text(f"""; FBX 7.3.0 project file
FBXHeaderExtension:  {{
    FBXHeaderVersion: 1003
    FBXVersion: 7300
}}
GlobalSettings:  {{
    Version: 1000
    Properties70:  {{
        P: "UpAxis", "int", "Integer", "",{axes[0]}
        P: "UpAxisSign", "int", "Integer", "",{axes[1]}
        P: "FrontAxis", "int", "Integer", "",{axes[2]}
        P: "FrontAxisSign", "int", "Integer", "",{axes[3]}
        P: "CoordAxis", "int", "Integer", "",0
        P: "CoordAxisSign", "int", "Integer", "",1
        P: "UnitScaleFactor", "double", "Number", "",1
    }}
}}
Objects:  {{
    Geometry: 1000, "Geometry::thing", "Mesh" {{
        Vertices: *{v.size} {{
            a: {nums(v)}
        }}
        PolygonVertexIndex: *{f.size} {{
            a: {nums(f)}
        }}
        GeometryVersion: 124
        LayerElementMaterial: 0 {{
            Version: 101
            MappingInformationType: "AllSame"
            ReferenceInformationType: "IndexToDirect"
            Materials: *1 {{
                a: 0
            }}
        }}
        Layer: 0 {{
            Version: 100
            LayerElement:  {{
                Type: "LayerElementMaterial"
                TypedIndex: 0
            }}
        }}
    }}
    Model: 2000, "Model::thing", "Mesh" {{
        Version: 232
    }}
    Material: 3000, "Material::paint", "" {{
        Version: 102
        ShadingModel: "lambert"
        Properties70:  {{
            P: "DiffuseColor", "Color", "", "A",{r},{g},{b}
        }}
    }}
}}
Connections:  {{
    C: "OO",2000,0
    C: "OO",1000,2000
    C: "OO",3000,2000
}}
""")
    return path


def write_ac3d(path: Path, rgb=(0.8, 0.05, 0.05), edges: bool = False) -> Path:
    """:func:`asymmetric_mesh` as an AC3D file (Y-up, as the format is), one object in a material of colour ``rgb``.
    With ``edges``, the first face's outline also as a closed-line surface among the faces, and a second object of a
    line surface only; the first with a ``data`` line whose text looks like a surface."""
    m = asymmetric_mesh()
    v = _z_up_to_y_up(np.asarray(m.vertices, dtype=np.float64))
    lines = ["AC3Db", 'MATERIAL "paint" rgb {} {} {}  amb 0.2 0.2 0.2  emis 0 0 0  spec 0 0 0  shi 10  trans 0'
             .format(*rgb), "OBJECT world", f"kids {2 if edges else 1}", "OBJECT poly", 'name "thing"']
    data = "SURF 0x12 refs 2"  # free text, which a reader must skip, not parse
    lines += [f"data {len(data)}", data] if edges else []
    lines.append(f"numvert {len(v)}")
    lines += [f"{x:.9g} {y:.9g} {z:.9g}" for x, y, z in v]
    faces = np.asarray(m.faces)
    lines.append(f"numsurf {len(faces) + edges}")
    for k, (a, b, c) in enumerate(faces):
        if edges and k == 1:
            lines += ["SURF 0x11", "mat 0", "refs 3", f"{a} 0 0", f"{b} 0 0", f"{c} 0 0"]  # a closed line
        lines += ["SURF 0x10", "mat 0", "refs 3", f"{a} 0 0", f"{b} 0 0", f"{c} 0 0"]
    lines.append("kids 0")
    if edges:
        lines += ["OBJECT poly", 'name "wire"', "numvert 2", "0 0 0", "0 0.1 0", "numsurf 1", "SURF 0x12", "mat 0",
                  "refs 2", "0 0 0", "1 0 0", "kids 0"]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_3mf(path: Path) -> Path:
    """:func:`asymmetric_mesh` as a 3MF package (Z-up, millimetres, as the format is)."""
    import zipfile

    m = asymmetric_mesh()
    verts = "".join(f'<vertex x="{x:.9g}" y="{y:.9g}" z="{z:.9g}"/>' for x, y, z in np.asarray(m.vertices))
    tris = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in np.asarray(m.faces))
    model = ('<?xml version="1.0" encoding="UTF-8"?><model unit="millimeter" xml:lang="en-US" '
             'xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02"><resources><object id="1" type="model">'
             f'<mesh><vertices>{verts}</vertices><triangles>{tris}</triangles></mesh></object></resources>'
             '<build><item objectid="1"/></build></model>')
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("[Content_Types].xml", '<?xml version="1.0" encoding="UTF-8"?><Types xmlns="http://schemas.openxml'
                   'formats.org/package/2006/content-types"><Default Extension="rels" ContentType="application/vnd.'
                   'openxmlformats-package.relationships+xml"/><Default Extension="model" ContentType="application/'
                   'vnd.ms-package.3dmanufacturing-3dmodel+xml"/></Types>')
        z.writestr("_rels/.rels", '<?xml version="1.0" encoding="UTF-8"?><Relationships xmlns="http://schemas.'
                   'openxmlformats.org/package/2006/relationships"><Relationship Target="/3D/3dmodel.model" Id="rel0" '
                   'Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/></Relationships>')
        z.writestr("3D/3dmodel.model", model)
    return path


def write_x3d(path: Path, rgb=(0.8, 0.05, 0.05), edges: bool = False, texture_urls: str = "") -> Path:
    """:func:`asymmetric_mesh` as an X3D file (Y-up, as the format is) under a Transform (a rotation about Y, a scale
    and a move) that its coordinates are stored undone by, in a Material of colour ``rgb``. With ``edges``, the first
    face's outline also as an IndexedLineSet in a Shape of its own. ``texture_urls``: an ImageTexture's url field
    (X3D's list of files to try in turn, e.g. '"a.png" "a.gif"')."""
    m = asymmetric_mesh()
    v = _z_up_to_y_up(np.asarray(m.vertices, dtype=np.float64))
    f = np.asarray(m.faces)
    c, s = np.cos(0.7), np.sin(0.7)
    node = np.array([[2 * c, 0, 2 * s, 0.3], [0, 2, 0, 0.5], [-2 * s, 0, 2 * c, 0.2], [0, 0, 0, 1]])  # T R_y(0.7) S(2)
    local = (np.linalg.inv(node) @ np.c_[v, np.ones(len(v))].T).T[:, :3]
    nums = " ".join(f"{x:.9g}" for x in local.ravel())
    idx = " ".join(f"{a} {b} {c} -1" for a, b, c in f)
    a, b, c = f[0]
    lines = (f'<Shape><IndexedLineSet coordIndex="{a} {b} {c} {a} -1"><Coordinate point="{nums}"/></IndexedLineSet>'
             '</Shape>') if edges else ""
    tex = f"<ImageTexture url='{texture_urls}'/>" if texture_urls else ""
    path.write_text(f"""<?xml version="1.0" encoding="UTF-8"?>
<X3D profile="Interchange" version="3.3"><Scene>
<Transform translation="0.3 0.5 0.2" rotation="0 1 0 0.7" scale="2 2 2">
<Shape><Appearance><Material diffuseColor="{rgb[0]} {rgb[1]} {rgb[2]}"/>{tex}</Appearance>
<IndexedFaceSet solid="true" coordIndex="{idx}"><Coordinate point="{nums}"/></IndexedFaceSet></Shape>{lines}
</Transform></Scene></X3D>
""")
    return path


def write_amf(path: Path) -> Path:
    """:func:`asymmetric_mesh` as an AMF file (Z-up, as the 3D-printing format is)."""
    m = asymmetric_mesh()
    verts = "".join(f"<vertex><coordinates><x>{x:.9g}</x><y>{y:.9g}</y><z>{z:.9g}</z></coordinates></vertex>"
                    for x, y, z in np.asarray(m.vertices))
    tris = "".join(f"<triangle><v1>{a}</v1><v2>{b}</v2><v3>{c}</v3></triangle>" for a, b, c in np.asarray(m.faces))
    path.write_text(f'<?xml version="1.0" encoding="UTF-8"?>\n<amf unit="meter"><object id="0"><mesh><vertices>{verts}'
                    f"</vertices><volume>{tris}</volume></mesh></object></amf>\n")
    return path


def write_dxf(path: Path, edges: bool = False) -> Path:
    """:func:`asymmetric_mesh` as a DXF file of 3DFACE entities (Z-up, as CAD is). With ``edges``, a LINE entity
    among them, as CAD drawings mix them."""
    m = asymmetric_mesh()
    v = np.asarray(m.vertices, dtype=np.float64)
    out = ["0", "SECTION", "2", "ENTITIES"]
    for k, (a, b, c) in enumerate(np.asarray(m.faces)):
        if edges and k == 1:
            out += ["0", "LINE", "8", "0", "10", f"{v[a][0]:.9g}", "20", f"{v[a][1]:.9g}", "30", f"{v[a][2]:.9g}",
                    "11", f"{v[b][0]:.9g}", "21", f"{v[b][1]:.9g}", "31", f"{v[b][2]:.9g}"]
        out += ["0", "3DFACE", "8", "0"]
        for i, q in enumerate((v[a], v[b], v[c], v[c])):  # a triangle: the fourth corner repeats the third
            out += [f"1{i}", f"{q[0]:.9g}", f"2{i}", f"{q[1]:.9g}", f"3{i}", f"{q[2]:.9g}"]
    out += ["0", "ENDSEC", "0", "EOF"]
    path.write_text("\n".join(out) + "\n")
    return path


def write_directx(path: Path) -> Path:
    """:func:`asymmetric_mesh` as a DirectX text .x file: Y-up and left-handed, as the format is, so a reader that
    does not turn its handedness would show the object mirrored."""
    m = asymmetric_mesh()
    v = np.asarray(m.vertices, dtype=np.float64)
    v = np.stack([v[:, 0], v[:, 2], v[:, 1]], axis=1)  # Blender (x, y, z) -> left-handed Y-up (x, z, y)
    f = np.asarray(m.faces)[:, ::-1]  # the same faces seen from outside in a left-handed frame
    verts = ",\n".join(f"{x:.9f};{y:.9f};{z:.9f};" for x, y, z in v)
    faces = ",\n".join(f"3;{a},{b},{c};" for a, b, c in f)
    path.write_text(f"xof 0303txt 0032\nMesh thing {{\n{len(v)};\n{verts};\n{len(f)};\n{faces};\n}}\n")
    return path


def write_3ds(path: Path) -> Path:
    """:func:`asymmetric_mesh` as a 3D Studio .3ds file (binary chunks; Z-up, as the format is), no material."""
    import struct

    m = asymmetric_mesh()
    v = np.asarray(m.vertices, dtype="<f4")
    f = np.asarray(m.faces, dtype="<u2")

    def chunk(cid: int, body: bytes) -> bytes:
        return struct.pack("<HI", cid, 6 + len(body)) + body

    verts = chunk(0x4110, struct.pack("<H", len(v)) + v.tobytes())
    faces = chunk(0x4120, struct.pack("<H", len(f)) + np.c_[f, np.zeros(len(f), "<u2")].astype("<u2").tobytes())
    obj = chunk(0x4000, b"thing\0" + chunk(0x4100, verts + faces))
    path.write_bytes(chunk(0x4D4D, chunk(0x0002, struct.pack("<I", 3)) + chunk(0x3D3D, obj)))
    return path


def write_ase_quad(path: Path, texture: str, tiling: float) -> Path:
    """A square in the z = 0 plane as a 3ds Max ASE file (Z-up), UV-mapped once over, its material's diffuse map
    ``texture`` repeated ``tiling`` times along U and V by the map's own UVW tiling (not by its UVs)."""
    corners = [(-1, -1, 0, 0, 0), (1, -1, 0, 1, 0), (1, 1, 0, 1, 1), (-1, 1, 0, 0, 1)]
    verts = " ".join(f"*MESH_VERTEX {i} {x} {y} {z}" for i, (x, y, z, _, _) in enumerate(corners))
    tverts = " ".join(f"*MESH_TVERT {i} {u} {v} 0" for i, (_, _, _, u, v) in enumerate(corners))
    faces = ("*MESH_FACE 0: A: 0 B: 1 C: 2 AB: 1 BC: 1 CA: 0 *MESH_SMOOTHING 1 *MESH_MTLID 0 "
             "*MESH_FACE 1: A: 0 B: 2 C: 3 AB: 0 BC: 1 CA: 1 *MESH_SMOOTHING 1 *MESH_MTLID 0")
    path.write_text(f"""*3DSMAX_ASCIIEXPORT 200
*MATERIAL_LIST {{
 *MATERIAL_COUNT 1
 *MATERIAL 0 {{
  *MATERIAL_NAME "paint"
  *MATERIAL_CLASS "Standard"
  *MATERIAL_DIFFUSE 1.0 1.0 1.0
  *MAP_DIFFUSE {{
   *MAP_NAME "Map #1"
   *MAP_CLASS "Bitmap"
   *MAP_SUBNO 1
   *MAP_AMOUNT 1.0
   *BITMAP "{texture}"
   *MAP_TYPE Screen
   *UVW_U_OFFSET 0.0
   *UVW_V_OFFSET 0.0
   *UVW_U_TILING {tiling}
   *UVW_V_TILING {tiling}
   *UVW_ANGLE 0.0
  }}
 }}
}}
*GEOMOBJECT {{
 *NODE_NAME "quad"
 *NODE_TM {{
  *NODE_NAME "quad"
  *TM_ROW0 1.0 0.0 0.0
  *TM_ROW1 0.0 1.0 0.0
  *TM_ROW2 0.0 0.0 1.0
  *TM_ROW3 0.0 0.0 0.0
 }}
 *MESH {{
  *MESH_NUMVERTEX 4
  *MESH_NUMFACES 2
  *MESH_VERTEX_LIST {{ {verts} }}
  *MESH_FACE_LIST {{ {faces} }}
  *MESH_NUMTVERTEX 4
  *MESH_TVERTLIST {{ {tverts} }}
  *MESH_NUMTVFACES 2
  *MESH_TFACELIST {{ *MESH_TFACE 0 0 1 2 *MESH_TFACE 1 0 2 3 }}
 }}
 *MATERIAL_REF 0
}}
""")
    return path


# Display P3 (D65) -> linear Rec.709, from the primaries (independent of lcms and of Blender's OCIO config).
P3_TO_709 = np.array([[1.2249401, -0.2249404, 0.0], [-0.0420569, 1.0420571, 0.0], [-0.0196376, -0.0786361, 1.0982735]])


def p3_profile() -> bytes:
    """Display P3 ICC profile shipped with Blender's colour management (found without importing bpy); skips the
    test where bpy's datafiles are not here."""
    import importlib.util

    import pytest

    spec = importlib.util.find_spec("bpy")
    found = sorted(Path(spec.origin).parent.glob("*/datafiles/colormanagement/icc/srgb_p3d65_display.icc")) \
        if spec and spec.origin else []
    if not found:
        pytest.skip("no Display P3 ICC profile (bpy's datafiles) here")
    return found[0].read_bytes()


def pycolmap_stages_in_this_process(monkeypatch) -> None:
    """Run recover-poses' pycolmap stages that go to a child process (``sfm._run_in_child``: matching, the focal
    length from the view graph) in this process instead, so that a test's monkeypatch of a pycolmap function
    reaches them."""
    import pycolmap

    from blender_mrvm.capture import sfm

    def in_process(call, args, kwargs, *rest, **options):
        return getattr(pycolmap, call)(*args, **kwargs)
        yield  # (a generator, as the stage it stands for)

    monkeypatch.setattr(sfm, "_run_in_child", in_process)
