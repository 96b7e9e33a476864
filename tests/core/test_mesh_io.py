"""Tests for core.formats.mesh_io (load/save) and core.formats.landmarks_io, on small meshes built in code."""

from __future__ import annotations

import json
import os

import numpy as np
import PIL.Image
import pytest
import trimesh

from core.face import Face, SurfacePoint
from core.formats.landmarks_io import LandmarkFileError, load_landmarks, save_landmarks
from core.formats.mesh_io import MeshLoadError, MeshSaveError, load_face, save_face

# A 200 mm square (two triangles' worth of vertices), the basis of the hand-written files.
SQUARE_V = """
v 0 0 0
v 200 0 0
v 200 200 0
v 0 200 0
"""


def write_text(path, text: str):
    """Write ``text`` (each line's indentation stripped) to ``path`` and return ``path``."""
    path.write_text("\n".join(line.strip() for line in text.strip().splitlines()) + "\n")
    return path


# ------------------------------------------------------------ round trips
def test_obj_round_trip_keeps_vertices_triangles_uv_texture_colours(grid_face, tmp_path):
    save_face(grid_face, tmp_path / "head.obj")
    assert {p.name for p in tmp_path.iterdir()} == {"head.obj", "head.mtl", "head.png"}
    face = load_face(tmp_path / "head.obj")
    np.testing.assert_allclose(face.vertices, grid_face.vertices, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(face.triangles, grid_face.triangles)
    np.testing.assert_allclose(face.uv, grid_face.uv, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(face.texture, grid_face.texture)
    np.testing.assert_array_equal(face.vertex_colors, grid_face.vertex_colors)
    assert face.metadata.notes == []
    assert (face.metadata.units, face.metadata.name) == ("mm", "head")
    assert face.metadata.source == str(tmp_path / "head.obj")


def test_obj_without_texture_writes_no_material(grid_face, tmp_path):
    plain = Face(grid_face.vertices, grid_face.triangles)
    save_face(plain, tmp_path / "plain.obj")
    assert [p.name for p in tmp_path.iterdir()] == ["plain.obj"]
    face = load_face(tmp_path / "plain.obj")
    np.testing.assert_allclose(face.vertices, plain.vertices, rtol=0, atol=1e-6)
    assert face.uv is None and face.texture is None and face.vertex_colors is None


def test_ply_round_trip_keeps_vertices_triangles_uv_colours(grid_face, tmp_path):
    save_face(grid_face, tmp_path / "head.ply")
    face = load_face(tmp_path / "head.ply")
    np.testing.assert_array_equal(face.vertices, grid_face.vertices)  # doubles: exact
    np.testing.assert_array_equal(face.triangles, grid_face.triangles)
    np.testing.assert_array_equal(face.uv, grid_face.uv)
    np.testing.assert_array_equal(face.vertex_colors, grid_face.vertex_colors)
    np.testing.assert_array_equal(face.texture, grid_face.texture)
    assert face.metadata.notes == []


def test_a_mimica_ply_keeps_named_parts_and_every_triangle_as_written(grid_face, tmp_path):
    """A face Mimica held (a project's embedded face: a cut scan with a mouth cavity) comes back exactly:
    its named parts, a zero-area triangle and an unused vertex included, so landmarks and the rig
    index it as before. Another program's PLY with the same defects is still repaired, with notes."""
    v = np.vstack([grid_face.vertices, grid_face.vertices[:1], [[1e3, 1e3, 1e3]]])   # a copy, an unused vertex
    n = len(grid_face.vertices)
    flat = [[0, 1, n]]                                                              # zero area (n is on 0)
    face = Face(v, np.vstack([grid_face.triangles, flat]), parts={"teeth": np.array([2, 3]), "eye": np.array([5])})
    save_face(face, tmp_path / "held.ply")
    back = load_face(tmp_path / "held.ply")
    np.testing.assert_array_equal(back.vertices, face.vertices)
    np.testing.assert_array_equal(back.triangles, face.triangles)
    assert {k: list(p) for k, p in back.parts.items()} == {"eye": [5], "teeth": [2, 3]}
    assert back.metadata.notes == []
    other = (tmp_path / "held.ply").read_bytes().replace(b"Written by Mimica", b"Written by Other ")
    (tmp_path / "other.ply").write_bytes(other)
    repaired = load_face(tmp_path / "other.ply")
    assert repaired.n_vertices == n and repaired.n_triangles == len(grid_face.triangles)   # both extras unused
    assert any("zero area" in note for note in repaired.metadata.notes)
    assert sorted(repaired.parts) == ["eye", "teeth"], "the parts still follow the vertices left"


def test_a_mimica_ply_keeps_the_faces_name_not_its_file_stem(grid_face, tmp_path):
    """A project's autosave embeds its face as <project>.face.ply: recovered, the face is still called
    what it was ("LeePerrySmith"), any name fitting the ASCII header; other PLYs are named by their stem."""
    import re

    from core.face import FaceMetadata

    for name in ("LeePerrySmith", 'José "scan" 2'):
        named = Face(grid_face.vertices, grid_face.triangles, metadata=FaceMetadata(name=name))
        save_face(named, tmp_path / "untitled-1.mimica.autosave.face.ply")
        assert load_face(tmp_path / "untitled-1.mimica.autosave.face.ply").metadata.name == name
    written = (tmp_path / "untitled-1.mimica.autosave.face.ply").read_bytes()
    (tmp_path / "plain.ply").write_bytes(re.sub(rb"comment MimicaName [^\n]*\n", b"", written, count=1))
    assert load_face(tmp_path / "plain.ply").metadata.name == "plain"        # a PLY without the comment


def test_ply_vertex_colours_survive_without_texture(grid_face, tmp_path):
    coloured = Face(grid_face.vertices, grid_face.triangles, vertex_colors=grid_face.vertex_colors)
    save_face(coloured, tmp_path / "c.ply")
    face = load_face(tmp_path / "c.ply")
    np.testing.assert_array_equal(face.vertex_colors, grid_face.vertex_colors)
    assert face.uv is None and face.texture is None


def test_ply_bakes_texture_into_vertex_colours(grid_face, tmp_path):
    texture = np.zeros((4, 4, 3), np.uint8)
    texture[:2] = (250, 10, 10)  # top half red: v > 0.5
    texture[2:] = (10, 10, 250)  # bottom half blue: v < 0.5
    face = Face(grid_face.vertices, grid_face.triangles, uv=grid_face.uv, texture=texture)
    save_face(face, tmp_path / "baked.ply")
    colors = load_face(tmp_path / "baked.ply").vertex_colors
    top, bottom = grid_face.uv[:, 1] == 1.0, grid_face.uv[:, 1] == 0.0
    assert top.sum() == 6 and bottom.sum() == 6
    assert (colors[top] == (250, 10, 10)).all()
    assert (colors[bottom] == (10, 10, 250)).all()


def test_glb_round_trip_keeps_vertices_triangles_uv_texture(grid_face, tmp_path):
    save_face(grid_face, tmp_path / "head.glb")
    assert [p.name for p in tmp_path.iterdir()] == ["head.glb"]
    face = load_face(tmp_path / "head.glb")
    np.testing.assert_allclose(face.vertices, grid_face.vertices, rtol=0, atol=1e-4)  # float32 metres
    np.testing.assert_array_equal(face.triangles, grid_face.triangles)
    np.testing.assert_allclose(face.uv, grid_face.uv, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(face.texture, grid_face.texture)
    # glTF is metres by specification: written in metres, scaled back on load
    assert face.metadata.notes == ["Scaled from metres to millimetres (bounding box 0.284 m)."]


def test_glb_vertex_colours_survive_without_texture(grid_face, tmp_path):
    coloured = Face(grid_face.vertices, grid_face.triangles, vertex_colors=grid_face.vertex_colors)
    save_face(coloured, tmp_path / "c.glb")
    np.testing.assert_array_equal(load_face(tmp_path / "c.glb").vertex_colors, grid_face.vertex_colors)


def test_glb_with_two_meshes_is_concatenated_with_note(tmp_path):
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    scene = trimesh.Scene()
    scene.add_geometry(box, node_name="a", geom_name="a")
    scene.add_geometry(box, node_name="b", geom_name="b", transform=trimesh.transformations.translation_matrix((0.2, 0, 0)))
    (tmp_path / "two.glb").write_bytes(scene.export(file_type="glb"))
    face = load_face(tmp_path / "two.glb")
    assert (face.n_vertices, face.n_triangles) == (16, 24)
    assert np.isclose(face.vertices[:, 0].max(), 250.0)  # node transform applied, then m -> mm
    assert "The file contains 2 separate meshes; they were combined into one face." in face.metadata.notes
    assert any("2 separate parts" in n for n in face.metadata.notes)


def test_stl_corners_are_welded(tmp_path):
    path = write_text(tmp_path / "sq.stl", """
        solid sq
        facet normal 0 0 1
        outer loop
        vertex 0 0 0
        vertex 200 0 0
        vertex 200 200 0
        endloop
        endfacet
        facet normal 0 0 1
        outer loop
        vertex 0 0 0
        vertex 200 200 0
        vertex 0 200 0
        endloop
        endfacet
        endsolid sq
    """)
    face = load_face(path)
    np.testing.assert_array_equal(face.vertices, [[0, 0, 0], [200, 0, 0], [200, 200, 0], [0, 200, 0]])
    np.testing.assert_array_equal(face.triangles, [[0, 1, 2], [0, 2, 3]])
    assert face.metadata.notes == []


def test_landmarks_round_trip_same_points_and_positions(grid_face, tmp_path):
    save_landmarks(grid_face, tmp_path / "lm.json")
    document = json.loads((tmp_path / "lm.json").read_text())
    assert (document["format"], document["version"], document["units"]) == ("mimica-landmarks", 1, "mm")
    assert [e["name"] for e in document["landmarks"]] == ["2.1", "8.3", "9.3"]
    notes = []
    loaded = load_landmarks(tmp_path / "lm.json", grid_face, notes=notes)
    assert loaded == grid_face.landmarks
    assert notes == []
    target = Face(grid_face.vertices, grid_face.triangles, landmarks=loaded)
    np.testing.assert_allclose(target.landmark_positions(["2.1", "8.3", "9.3"]), grid_face.landmark_positions(["2.1", "8.3", "9.3"]))


def test_landmarks_load_through_mesh_round_trip(grid_face, tmp_path):
    save_face(grid_face, tmp_path / "f.obj")
    save_landmarks(grid_face, tmp_path / "f.json")
    face = load_face(tmp_path / "f.obj")
    for name, point in load_landmarks(tmp_path / "f.json", face).items():
        face.set_landmark(name, point)
    np.testing.assert_allclose(face.landmark_positions(), grid_face.landmark_positions(), atol=1e-6)


# ------------------------------------------------------------------ units
@pytest.mark.parametrize(
    ("scale", "factor", "note"),
    [
        (0.001, 1000.0, "Scaled from metres to millimetres (bounding box 0.284 m)."),
        (0.1, 10.0, "Scaled from centimetres to millimetres (bounding box 28.4 cm)."),
        (1.0, 1.0, None),
    ],
)
def test_units_detected_from_bounding_box(grid_face, tmp_path, scale, factor, note):
    # grid face: 200 x 200 mm, bounding-box diagonal 284 mm
    small = Face(grid_face.vertices * scale, grid_face.triangles)
    save_face(small, tmp_path / "u.obj")
    face = load_face(tmp_path / "u.obj")
    np.testing.assert_allclose(face.vertices, small.vertices * factor, rtol=1e-9)
    assert face.metadata.notes == ([] if note is None else [note])
    assert face.metadata.units == "mm"


# ----------------------------------------------------------------- repairs
def test_quad_and_pentagon_are_triangulated_with_note(tmp_path):
    path = write_text(tmp_path / "poly.obj", SQUARE_V + """
        v 300 100 0
        v 300 300 0
        f 1 2 3 4
        f 2 5 6 3 3
        f 2 5 6
    """)
    face = load_face(path)
    # quad -> 2 triangles; pentagon (with a repeated corner) -> 3 fan triangles,
    # one of which repeats vertex 3 and is dropped; the lone triangle duplicates one of the fan
    assert "2 polygons with more than 3 corners (quads or n-gons) were split into triangles." in face.metadata.notes
    np.testing.assert_array_equal(face.triangles, [[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]])
    assert "Removed degenerate faces: 1 with a repeated vertex." in face.metadata.notes
    assert "Removed 1 duplicate face (the same three vertices listed again)." in face.metadata.notes


def test_duplicate_faces_removed_with_count(tmp_path):
    path = write_text(tmp_path / "dup.obj", SQUARE_V + """
        f 1 2 3
        f 1 3 4
        f 1 2 3
        f 3 1 4
        f 2 3 1
    """)
    face = load_face(path)
    np.testing.assert_array_equal(face.triangles, [[0, 1, 2], [0, 2, 3]])
    assert face.metadata.notes == ["Removed 3 duplicate faces (the same three vertices listed again)."]


def test_degenerate_faces_removed_with_counts_of_each_kind(tmp_path):
    path = write_text(tmp_path / "deg.obj", SQUARE_V + """
        v 100 0 0
        f 1 2 3
        f 1 3 4
        f 1 1 2
        f 1 5 2
        f 1 2
    """)
    face = load_face(path)
    np.testing.assert_array_equal(face.triangles, [[0, 1, 2], [0, 2, 3]])
    assert face.n_vertices == 4  # vertex 5 was only used by the zero-area face
    assert face.metadata.notes == [
        "Removed degenerate faces: 1 with fewer than 3 corners, 1 with a repeated vertex, 1 with zero area.",
        "Removed 1 vertex that no face uses.",
    ]


def test_unreferenced_vertices_removed_keeping_uv_aligned(tmp_path):
    path = write_text(tmp_path / "unused.obj", """
        v 0 0 0
        v 999 999 999
        v 200 0 0
        v 200 200 0
        vt 0 0
        vt 0.5 0.5
        vt 1 0
        vt 1 1
        f 1/1 3/3 4/4
    """)
    face = load_face(path)
    np.testing.assert_array_equal(face.vertices, [[0, 0, 0], [200, 0, 0], [200, 200, 0]])
    np.testing.assert_array_equal(face.uv, [[0, 0], [1, 0], [1, 1]])
    np.testing.assert_array_equal(face.triangles, [[0, 1, 2]])
    assert face.metadata.notes == ["Removed 1 vertex that no face uses."]


def test_two_components_are_kept_with_note(tmp_path):
    path = write_text(tmp_path / "two.obj", SQUARE_V + """
        v 300 0 0
        v 400 0 0
        v 400 100 0
        f 1 2 3
        f 1 3 4
        f 5 6 7
    """)
    face = load_face(path)
    assert face.n_triangles == 3 and face.n_components == 2
    assert face.metadata.notes == [
        "The mesh has 2 separate parts (connected components); all were kept. Loose parts can be "
        "removed in MeshLab: Filters > Cleaning and Repairing > Remove Isolated pieces."
    ]


def test_uv_seam_duplicates_vertex_after_the_others_and_is_one_part(tmp_path):
    path = write_text(tmp_path / "seam.obj", SQUARE_V + """
        vt 0 0
        vt 1 0
        vt 1 1
        vt 0 1
        vt 0.5 0.5
        f 1/1 2/2 3/3
        f 1/5 3/3 4/4
    """)
    face = load_face(path)
    # vertex 1 is used with vt 1 and vt 5: the second pair becomes vertex 4 (0-based)
    np.testing.assert_array_equal(face.vertices, [[0, 0, 0], [200, 0, 0], [200, 200, 0], [0, 200, 0], [0, 0, 0]])
    np.testing.assert_array_equal(face.triangles, [[0, 1, 2], [4, 2, 3]])
    np.testing.assert_array_equal(face.uv, [[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]])
    assert face.metadata.notes == [
        "1 vertex on texture seams was duplicated so that each vertex has a single texture coordinate."
    ]


def test_obj_negative_indices_and_full_corner_layout(tmp_path):
    path = write_text(tmp_path / "rel.obj", """
        v 0 0 0
        v 200 0 0
        v 200 200 0
        vn 0 0 1
        f -3//1 -2//1 -1//1
        v 0 200 0
        f 1//1 3//1 -1//1
    """)
    face = load_face(path)
    np.testing.assert_array_equal(face.triangles, [[0, 1, 2], [0, 2, 3]])


def test_missing_texture_loads_geometry_with_note(tmp_path):
    write_text(tmp_path / "m.mtl", "newmtl skin\nmap_Kd skin.png")
    path = write_text(tmp_path / "m.obj", "mtllib m.mtl\nusemtl skin\n" + SQUARE_V + """
        vt 0 0
        vt 1 0
        vt 1 1
        vt 0 1
        f 1/1 2/2 3/3 4/4
    """)
    face = load_face(path)
    assert face.texture is None
    assert face.uv is not None and face.n_triangles == 2
    assert f"The texture image 'skin.png' was not found (looked in '{tmp_path}'); the face is shown with plain shading, without texture." in face.metadata.notes


def test_unreadable_texture_loads_geometry_with_note(tmp_path):
    (tmp_path / "skin.png").write_bytes(b"this is not a png")
    write_text(tmp_path / "m.mtl", "newmtl skin\nmap_Kd skin.png")
    path = write_text(tmp_path / "m.obj", "mtllib m.mtl\nusemtl skin\n" + SQUARE_V + "vt 0 0\nf 1/1 2/1 3/1")
    face = load_face(path)
    assert face.texture is None
    assert any(n.startswith("The texture image 'skin.png' could not be read (") for n in face.metadata.notes)


def test_texture_resolved_relative_to_mtl_and_converted_to_rgb(tmp_path):
    (tmp_path / "materials" / "maps").mkdir(parents=True)
    rgba = np.zeros((2, 3, 4), np.uint8)
    rgba[..., 0], rgba[..., 3] = 77, 10
    PIL.Image.fromarray(rgba, "RGBA").save(tmp_path / "materials" / "maps" / "skin.png")
    write_text(tmp_path / "materials" / "m.mtl", "newmtl skin\nmap_Kd -s 1 1 1 maps/skin.png")
    path = write_text(tmp_path / "m.obj", "mtllib materials/m.mtl\nusemtl skin\n" + SQUARE_V + "vt 0 0\nf 1/1 2/1 3/1")
    face = load_face(path)
    assert face.texture.shape == (2, 3, 3) and face.texture.dtype == np.uint8
    assert (face.texture == (77, 0, 0)).all()


def test_greyscale_texture_expanded_to_rgb(tmp_path):
    PIL.Image.fromarray(np.full((2, 2), 123, np.uint8), "L").save(tmp_path / "g.png")
    write_text(tmp_path / "m.mtl", "newmtl skin\nmap_Kd g.png")
    path = write_text(tmp_path / "m.obj", "mtllib m.mtl\n" + SQUARE_V + "vt 0 0\nf 1/1 2/1 3/1")
    assert (load_face(path).texture == 123).all()


def ascii_ply(n_vertices: int, n_faces: int, body: str) -> str:
    """An ASCII PLY announcing ``n_vertices`` (x y z) and ``n_faces`` (vertex lists), then ``body``."""
    return ("ply\nformat ascii 1.0\n"
            f"element vertex {n_vertices}\nproperty float x\nproperty float y\nproperty float z\n"
            f"element face {n_faces}\nproperty list uchar int vertex_indices\nend_header\n{body}\n")


def test_ply_quad_is_triangulated_with_note(tmp_path):
    path = write_text(tmp_path / "q.ply", ascii_ply(4, 1, "0 0 0\n200 0 0\n200 200 0\n0 200 0\n4 0 1 2 3"))
    face = load_face(path)
    assert face.n_triangles == 2 and face.n_vertices == 4
    assert face.metadata.notes == ["1 polygon with more than 3 corners (quads or n-gons) was split into triangles."]


def test_progress_reports_increasing_fractions_ending_at_one(grid_face, tmp_path):
    save_face(grid_face, tmp_path / "p.obj")
    calls = []
    load_face(tmp_path / "p.obj", progress=lambda fraction, message: calls.append((fraction, message)))
    fractions = [f for f, _ in calls]
    assert fractions == sorted(fractions) and fractions[0] == 0.0 and fractions[-1] == 1.0
    assert calls[-1][1] == "Loaded p.obj"


# ---------------------------------------------------------------- bad input
def test_nonexistent_path(tmp_path):
    with pytest.raises(MeshLoadError, match=r"The file '.*nothere\.obj' does not exist\. Check that the path"):
        load_face(tmp_path / "nothere.obj")


def test_directory_is_refused(tmp_path):
    (tmp_path / "folder.obj").mkdir()
    with pytest.raises(MeshLoadError, match=r"is a folder, not a mesh file"):
        load_face(tmp_path / "folder.obj")


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root can read files without read permission")
def test_unreadable_file(tmp_path):
    path = write_text(tmp_path / "secret.obj", SQUARE_V + "f 1 2 3")
    path.chmod(0)
    with pytest.raises(MeshLoadError, match=r"not allowed to read"):
        load_face(path)


def test_unknown_extension_lists_supported_formats(tmp_path):
    path = write_text(tmp_path / "cloud.xyz", "0 0 0\n1 1 1")
    with pytest.raises(MeshLoadError, match=r"unsupported file type \('\.xyz'\)\. Mimica can load \.obj, \.ply, \.stl, \.gltf, \.glb"):
        load_face(path)


def test_empty_file(tmp_path):
    (tmp_path / "e.ply").write_bytes(b"")
    with pytest.raises(MeshLoadError, match=r"'e\.ply' is empty \(0 bytes\)"):
        load_face(tmp_path / "e.ply")


def test_obj_parse_failure_names_format_and_reason(tmp_path):
    path = write_text(tmp_path / "bad.obj", "v 0 0 0\nv 1 zero 0\nv 1 1 0\nf 1 2 3")
    with pytest.raises(MeshLoadError, match=r"Could not read 'bad\.obj' as an OBJ file: could not convert string to float: 'zero'"):
        load_face(path)


def test_obj_face_index_out_of_range(tmp_path):
    path = write_text(tmp_path / "trunc.obj", SQUARE_V + "f 1 2 9")
    with pytest.raises(MeshLoadError, match=r"OBJ file: a face refers to vertex 9, but the file defines only 4 vertices"):
        load_face(path)


def test_ply_parse_failure_names_format(tmp_path):
    (tmp_path / "junk.ply").write_bytes(b"this is not a ply file at all\n")
    with pytest.raises(MeshLoadError, match=r"Could not read 'junk\.ply' as a PLY file: .*try exporting it again"):
        load_face(tmp_path / "junk.ply")


def test_point_cloud_ply_has_zero_faces(tmp_path):
    path = write_text(tmp_path / "cloud.ply", """
        ply
        format ascii 1.0
        element vertex 3
        property float x
        property float y
        property float z
        end_header
        0 0 0
        1 0 0
        0 1 0
    """)
    with pytest.raises(MeshLoadError, match=r"contains no faces \(3 points only\): it is a point cloud"):
        load_face(path)


def test_ascii_ply_cut_short_says_so_not_point_cloud(tmp_path):
    path = write_text(tmp_path / "cut.ply", ascii_ply(3, 1, "0 0 0\n1 0 0"))   # 2 of 3 vertices, no face
    with pytest.raises(MeshLoadError, match=r"'cut\.ply' ends early: its header announces 3 vertices and 1 face, "
                                            r"the file holds 2 vertices and 0 faces"):
        load_face(path)


def test_binary_ply_cut_short_says_so(grid_face, tmp_path):
    save_face(grid_face, tmp_path / "whole.ply")
    data = (tmp_path / "whole.ply").read_bytes()
    (tmp_path / "half.ply").write_bytes(data[: len(data) - 40])
    with pytest.raises(MeshLoadError, match=rf"'half\.ply' does not hold what its header announces "
                                            rf"\({grid_face.n_vertices} vertices, {grid_face.n_triangles} faces\): .*cut short"):
        load_face(tmp_path / "half.ply")


def test_obj_with_nothing_readable_is_not_called_a_point_cloud(tmp_path):
    (tmp_path / "junk.obj").write_bytes(b"this is not a mesh\n\x00\x01garbage")
    with pytest.raises(MeshLoadError, match=r"'junk\.obj' holds no vertices or faces Mimica can read"):
        load_face(tmp_path / "junk.obj")


def test_point_cloud_obj_has_zero_faces(tmp_path):
    with pytest.raises(MeshLoadError, match=r"contains no faces \(4 points only\)"):
        load_face(write_text(tmp_path / "pts.obj", SQUARE_V))


def test_nan_vertices_are_counted(tmp_path):
    path = write_text(tmp_path / "nan.obj", SQUARE_V + """
        v nan 0 0
        v 0 inf 0
        v nan nan nan
        f 1 2 3
        f 1 5 6
        """)
    # vertex 7 is non-finite too but unused: it is dropped, not counted
    with pytest.raises(MeshLoadError, match=r"'nan\.obj' has 2 vertices with invalid coordinates \(NaN or infinity\)"):
        load_face(path)


def test_too_many_triangles_refused_with_decimation_hint(grid_face, tmp_path):
    save_face(grid_face, tmp_path / "big.obj")
    with pytest.raises(
        MeshLoadError,
        match=r"has 40 triangles, more than the 39 Mimica accepts\. Please decimate it first, e\.g\. in MeshLab: "
        r"Filters > Remeshing > Quadric Edge Collapse Decimation, or Blender's Decimate modifier",
    ):
        load_face(tmp_path / "big.obj", max_triangles=39)
    assert load_face(tmp_path / "big.obj", max_triangles=40).n_triangles == 40


def test_progress_exception_propagates_unchanged(grid_face, tmp_path):
    save_face(grid_face, tmp_path / "c.obj")

    def cancel(fraction, message):
        if fraction > 0.5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        load_face(tmp_path / "c.obj", progress=cancel)


# --------------------------------------------------------------- save errors
def test_save_unknown_extension(grid_face, tmp_path):
    with pytest.raises(MeshSaveError, match=r"Cannot save as '\.stl': Mimica saves faces as \.obj, \.ply, \.glb"):
        save_face(grid_face, tmp_path / "x.stl")
    assert list(tmp_path.iterdir()) == []


def test_save_into_missing_folder(grid_face, tmp_path):
    with pytest.raises(MeshSaveError, match=r"the folder '.*nowhere' does not exist"):
        save_face(grid_face, tmp_path / "nowhere" / "x.obj")


def test_save_replaces_existing_file_and_leaves_no_temporary(grid_face, tmp_path):
    (tmp_path / "x.ply").write_bytes(b"old")
    save_face(grid_face, tmp_path / "x.ply")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.ply", "x.png"]
    assert load_face(tmp_path / "x.ply").n_vertices == grid_face.n_vertices


# ----------------------------------------------------------- landmark errors
def _landmark_file(tmp_path, entries, **header):
    document = {"format": "mimica-landmarks", "version": 1, "units": "mm", "landmarks": entries} | header
    path = tmp_path / "lm.json"
    path.write_text(json.dumps(document, indent=2))
    return path


def test_landmark_triangle_out_of_range_falls_back_to_xyz(grid_face, tmp_path):
    flat = Face(grid_face.vertices * (1.0, 1.0, 0.0), grid_face.triangles, landmarks=grid_face.landmarks)
    above = flat.vertices[8] + (0.0, 0.0, 5.0)  # 5 mm above interior vertex 8 of the flat grid
    path = _landmark_file(tmp_path, [{"name": "x", "xyz": list(above), "triangle": 9999, "barycentric": [1, 0, 0]}])
    notes = []
    loaded = load_landmarks(path, flat, notes=notes)
    corners = flat.vertices[flat.triangles[loaded["x"].triangle]]
    np.testing.assert_allclose(np.asarray(loaded["x"].barycentric) @ corners, flat.vertices[8], atol=1e-9)
    assert notes == [
        "Landmark 'x' refers to triangle 9999, which this face does not have (40 triangles); it was placed at "
        "the surface point closest to its saved position (5.00 mm away). The file was probably made for another mesh."
    ]
    assert flat.landmarks == grid_face.landmarks  # the face is not modified


def test_landmark_position_mismatch_is_noted(grid_face, tmp_path):
    path = _landmark_file(tmp_path, [{"name": "x", "xyz": [0, 0, 500], "triangle": 0, "barycentric": [1, 0, 0]}])
    notes = []
    assert load_landmarks(path, grid_face, notes=notes) == {"x": SurfacePoint(0, (1.0, 0.0, 0.0))}
    distance = np.linalg.norm(grid_face.vertices[grid_face.triangles[0, 0]] - (0, 0, 500))
    assert notes == [
        f"Landmark 'x' is {distance:.1f} mm from its saved position; the file may have been made for "
        "another mesh or another pose."
    ]


def test_landmark_barycentric_not_summing_to_one_names_landmark(grid_face, tmp_path):
    path = _landmark_file(tmp_path, [{"name": "2.1", "xyz": [0, 0, 0], "triangle": 0, "barycentric": [0.5, 0.5, 0.5]}])
    with pytest.raises(LandmarkFileError, match=r"landmark '2\.1' has barycentric weights that sum to 1\.5 instead of 1"):
        load_landmarks(path, grid_face)


def test_landmark_invalid_json_gives_line_number(grid_face, tmp_path):
    path = tmp_path / "broken.json"
    path.write_text('{\n  "format": "mimica-landmarks",\n  "version": 1,\n  "landmarks": [,]\n}\n')
    with pytest.raises(LandmarkFileError, match=r"'broken\.json' is not valid JSON: .* at line 4, column 17"):
        load_landmarks(path, grid_face)


def test_landmark_wrong_format(grid_face, tmp_path):
    with pytest.raises(LandmarkFileError, match=r"is not a Mimica landmark file \(its \"format\" is 'other'"):
        load_landmarks(_landmark_file(tmp_path, [], format="other"), grid_face)


def test_landmark_wrong_version(grid_face, tmp_path):
    with pytest.raises(LandmarkFileError, match=r"landmark file of version 2; this Mimica reads version 1 only"):
        load_landmarks(_landmark_file(tmp_path, [], version=2), grid_face)


def test_landmark_missing_file(grid_face, tmp_path):
    with pytest.raises(LandmarkFileError, match=r"The landmark file '.*none\.json' does not exist"):
        load_landmarks(tmp_path / "none.json", grid_face)


def test_landmark_out_of_range_without_xyz_is_an_error(grid_face, tmp_path):
    path = _landmark_file(tmp_path, [{"name": "y", "triangle": 40, "barycentric": [1, 0, 0]}])
    with pytest.raises(LandmarkFileError, match=r"landmark 'y' refers to triangle 40, but the face has only 40 triangles"):
        load_landmarks(path, grid_face)


def test_landmark_duplicate_name_is_an_error(grid_face, tmp_path):
    entry = {"name": "y", "triangle": 1, "barycentric": [1, 0, 0]}
    with pytest.raises(LandmarkFileError, match=r"landmark 'y' appears more than once"):
        load_landmarks(_landmark_file(tmp_path, [entry, entry]), grid_face)


# ------------------------------------------------------------- more formats
def test_texture_without_uv_is_ignored_with_note(tmp_path):
    PIL.Image.fromarray(np.zeros((2, 2, 3), np.uint8)).save(tmp_path / "skin.png")
    write_text(tmp_path / "m.mtl", "newmtl skin\nmap_Kd skin.png")
    face = load_face(write_text(tmp_path / "m.obj", "mtllib m.mtl\nusemtl skin\n" + SQUARE_V + "f 1 2 3 4"))
    assert face.texture is None and face.uv is None
    assert face.metadata.notes == [
        "1 polygon with more than 3 corners (quads or n-gons) was split into triangles.",
        "The texture was ignored because the mesh has no texture coordinates.",
    ]


def test_obj_mixed_corner_layouts_and_non_ascii_comment(tmp_path):
    path = tmp_path / "mixed.obj"
    path.write_text("# visage modélisé à la main\n" + SQUARE_V + "vt 0 0\nvt 1 0\nvt 1 1\nf 1/1 2/2 3/3\nf 1 3 4\n",
                    encoding="utf-8")
    face = load_face(path)
    np.testing.assert_array_equal(face.triangles, [[0, 1, 2], [0, 2, 3]])
    assert face.uv is None
    assert face.metadata.notes == ["Some faces have no valid texture coordinates, so the texture was not used."]


def test_ply_per_corner_texcoords_give_per_vertex_uv(tmp_path):
    path = write_text(tmp_path / "wedge.ply", """
        ply
        format ascii 1.0
        element vertex 4
        property float x
        property float y
        property float z
        element face 2
        property list uchar int vertex_indices
        property list uchar float texcoord
        end_header
        0 0 0
        200 0 0
        200 200 0
        0 200 0
        3 0 1 2 6 0 0 1 0 1 1
        3 0 2 3 6 0 0 1 1 0 1
    """)
    face = load_face(path)
    assert face.n_vertices == 4 and face.n_triangles == 2
    np.testing.assert_allclose(face.uv, face.vertices[:, :2] / 200.0)  # uv follows the position


def test_texture_with_foreign_absolute_path_found_next_to_mtl(tmp_path):
    PIL.Image.fromarray(np.full((2, 2, 3), 9, np.uint8)).save(tmp_path / "skin.png")
    write_text(tmp_path / "m.mtl", "newmtl skin\nmap_Kd C:\\Users\\artist\\scans\\skin.png")
    path = write_text(tmp_path / "m.obj", "mtllib m.mtl\nusemtl skin\n" + SQUARE_V + "vt 0 0\nf 1/1 2/1 3/1")
    face = load_face(path)
    assert (face.texture == 9).all()
    assert face.metadata.notes == ["Removed 1 vertex that no face uses."]  # no texture note


def test_two_textured_materials_use_the_first_with_note(tmp_path):
    for name, value in (("a.png", 1), ("b.png", 2)):
        PIL.Image.fromarray(np.full((2, 2, 3), value, np.uint8)).save(tmp_path / name)
    write_text(tmp_path / "m.mtl", "newmtl A\nmap_Kd a.png\nnewmtl B\nmap_Kd b.png")
    path = write_text(tmp_path / "m.obj", "mtllib m.mtl\n" + SQUARE_V + "vt 0 0\nusemtl B\nf 1/1 2/1 3/1\nusemtl A\nf 1/1 3/1 4/1")
    face = load_face(path)
    assert (face.texture == 2).all()
    assert face.metadata.notes == [
        "The mesh uses 2 texture images; Mimica shows one per face, so only 'b.png' is used and other parts "
        "may look wrongly coloured."
    ]


def test_load_texture_image_reads_any_mode_and_refuses_non_images(tmp_path):
    from PIL import Image

    from core.formats.mesh_io import MeshLoadError, load_texture_image

    grey16 = tmp_path / "depthlike.png"
    Image.fromarray(np.full((4, 6), 65535, np.uint16)).save(grey16)
    rgb = load_texture_image(grey16)
    assert rgb.shape == (4, 6, 3) and rgb.dtype == np.uint8 and (rgb == 255).all()   # scaled, not clipped garbage
    (tmp_path / "bad.jpg").write_text("hello")
    with pytest.raises(MeshLoadError, match="bad.jpg' is not an image"):
        load_texture_image(tmp_path / "bad.jpg")
