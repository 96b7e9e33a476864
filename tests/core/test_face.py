"""Face: validation, cached derived data, surface-point landmarks that follow deformation."""

import numpy as np
import pytest

from core.face import Face, SurfacePoint, VertexNormals, coincident_skin_vertices, vertex_normals
from tests.core.conftest import run_fresh_python


def unit_square(z=0.0):
    v = np.array([[0, 0, z], [1, 0, z], [1, 1, z], [0, 1, z]], float)
    t = np.array([[0, 1, 2], [0, 2, 3]])
    return Face(v, t)


def test_arrays_are_read_only_copies():
    v = np.zeros((3, 3)); v[1, 0] = 1; v[2, 1] = 1
    face = Face(v, [[0, 1, 2]])
    v[0, 0] = 99.0
    assert face.vertices[0, 0] == 0.0
    with pytest.raises(ValueError):
        face.vertices[0, 0] = 1.0


def test_shape_and_index_validation():
    with pytest.raises(ValueError, match="vertices must have shape"):
        Face(np.zeros((3, 2)), [[0, 1, 2]])
    with pytest.raises(ValueError, match="only 3 vertices"):
        Face(np.zeros((3, 3)), [[0, 1, 3]])
    with pytest.raises(ValueError, match="uv has 2 rows"):
        Face(np.eye(3), [[0, 1, 2]], uv=np.zeros((2, 2)))
    with pytest.raises(ValueError, match="sum to 1"):
        SurfacePoint(0, (0.5, 0.5, 0.5))


def test_normals_edges_adjacency_components():
    face = unit_square()
    assert np.allclose(face.face_normals, [[0, 0, 1], [0, 0, 1]])
    assert np.allclose(face.vertex_normals, np.tile([0, 0, 1], (4, 1)))
    assert face.edges.tolist() == [[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]]
    assert face.adjacency[0].nnz == 3 and face.adjacency[1].nnz == 2
    assert face.n_components == 1
    two = Face(np.concatenate([face.vertices, face.vertices + 5]), np.concatenate([face.triangles, face.triangles + 4]))
    assert two.n_components == 2


def test_vertex_normals_of_a_sphere_point_outward():
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    n = vertex_normals(np.asarray(sphere.vertices), np.asarray(sphere.faces))
    radial = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", n, radial).min() > 0.99


def split_tent():
    """A folded sheet (a tent along x = 0) in one piece, the same sheet whose two halves are separate
    vertices along the ridge, and that one's (left copy, right copy) ridge vertices."""
    xs, ys = np.linspace(-2, 2, 5), np.linspace(0, 3, 4)
    grid = np.array([[x, y, 2.0 - 0.5 * abs(x)] for y in ys for x in xs])
    tri = []
    for j in range(3):
        for i in range(4):
            a = j * 5 + i
            tri += [[a, a + 1, a + 6], [a, a + 6, a + 5]]
    whole = Face(grid, np.array(tri))
    ridge = np.flatnonzero(grid[:, 0] == 0)
    copies = len(grid) + np.arange(len(ridge))
    lut = np.arange(len(grid))
    split_tri = np.array(tri)
    right = (grid[split_tri].mean(axis=1)[:, 0] > 0)
    lut_right = lut.copy()
    lut_right[ridge] = copies
    split_tri[right] = lut_right[split_tri[right]]
    split = Face(np.concatenate([grid, grid[ridge]]), split_tri)
    return whole, split, ridge, copies


def test_welded_normals_hide_a_seam_until_it_opens():
    whole, split, ridge, copies = split_tent()
    members, groups = coincident_skin_vertices(split)
    assert set(members.tolist()) == set(ridge.tolist()) | set(copies.tolist())
    plain = VertexNormals(split.triangles, split.n_vertices)(split.vertices)
    welded = VertexNormals(split.triangles, split.n_vertices, welds=(members, groups))(split.vertices)
    # Unwelded, each side of the ridge keeps its own slope (a crease); welded, the ridge is shaded as
    # the sheet in one piece is: straight up (the two slopes are symmetric).
    assert np.degrees(np.arccos(np.clip((plain[ridge] * plain[copies]).sum(axis=1), -1, 1))).min() > 40
    assert np.allclose(welded[ridge], [0, 0, 1]) and np.allclose(welded[copies], [0, 0, 1])
    others = np.setdiff1d(np.arange(split.n_vertices), members)
    assert np.array_equal(welded[others], plain[others])
    # The right half pulled away (a cut that opened): each side shades on its own again.
    moved = split.vertices.copy()
    moved[copies, 0] += 0.5
    opened = VertexNormals(split.triangles, split.n_vertices, welds=(members, groups))(moved)
    assert np.allclose(opened, VertexNormals(split.triangles, split.n_vertices)(moved))


def test_parts_and_sharp_folds_are_not_welded():
    whole, split, ridge, copies = split_tent()
    teeth = Face(split.vertices, split.triangles, parts={"teeth_upper": copies})
    assert len(coincident_skin_vertices(teeth)[0]) == 0
    # Fold the right half over (a lip turning into the mouth): the copies' normals turn far away.
    folded = split.vertices.copy()
    right = folded[:, 0] > 0
    folded[right, 2] = 2.0 - 0.9 * folded[right, 0]
    folded[right, 0] *= -0.6                                  # under the left half
    sharp = Face(folded, split.triangles)
    assert len(coincident_skin_vertices(sharp)[0]) == 0


def test_landmarks_follow_deformation_and_stay_on_surface():
    face = unit_square()
    face.set_landmark("centre", SurfacePoint(0, (1 / 3, 1 / 3, 1 / 3)))
    assert face.landmark_position("centre") == pytest.approx([2 / 3, 1 / 3, 0])
    lifted = face.vertices + [0, 0, 7.0]
    moved = face.with_vertices(lifted)
    assert moved.landmark_position("centre") == pytest.approx([2 / 3, 1 / 3, 7.0])
    assert face.landmark_positions(vertices=lifted) == pytest.approx(np.array([[2 / 3, 1 / 3, 7.0]]))
    # Topology caches are shared, not recomputed.
    assert moved._topology is face._topology
    with pytest.raises(ValueError, match="triangle 5"):
        face.set_landmark("bad", SurfacePoint(5, (1, 0, 0)))
    with pytest.raises(KeyError, match="nope"):
        face.landmark_positions(["nope"])


def test_closest_surface_point_and_rays():
    face = unit_square()
    point = face.surface_point([0.25, 0.75, 3.0])
    assert face.triangles[point.triangle].tolist() == [0, 2, 3]
    closest, tri, bary = face.closest_surface_points([[0.25, 0.75, 3.0], [2.0, 0.5, 0.0]])
    assert closest == pytest.approx(np.array([[0.25, 0.75, 0.0], [1.0, 0.5, 0.0]]))
    hits, ray, _tri = face.ray_hits([[0.5, 0.2, 5.0], [3.0, 3.0, 5.0]], [[0, 0, -1], [0, 0, -1]])
    assert ray.tolist() == [0] and hits == pytest.approx(np.array([[0.5, 0.2, 0.0]]))
    assert face.kdtree.query([0.9, 0.1, 0.0])[1] == 1


def test_vertex_normals_known_answers():
    import trimesh

    from core.face import VertexNormals

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    normals = VertexNormals(sphere.faces, len(sphere.vertices))(np.asarray(sphere.vertices))
    radial = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", normals, radial).min() > 0.999  # outward, unit, radial
    plane = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 2, 2]], float)
    tri = np.array([[0, 1, 2], [1, 3, 2]])
    n = vertex_normals(plane, tri)
    assert np.allclose(n[:4], [0, 0, 1]) and np.allclose(n[4], 0)  # unused vertex: zero, not NaN


def test_scaled_and_retextured_copies_keep_landmarks(grid_face):
    face = grid_face
    big = face.scaled(10.0)
    assert np.allclose(big.vertices, face.vertices * 10.0) and big.landmarks == face.landmarks
    for name in face.landmark_names:
        assert np.allclose(big.landmark_position(name), 10.0 * face.landmark_position(name))
    with pytest.raises(ValueError, match="positive"):
        face.scaled(0.0)
    image = np.full((8, 8, 3), 200, np.uint8)
    retextured = face.with_texture(image)   # the grid face has uv
    assert np.array_equal(retextured.texture, image) and retextured.landmarks == face.landmarks
    with pytest.raises(ValueError, match="texture coordinates"):
        Face(face.vertices, face.triangles).with_texture(image)


def test_with_flipped_texture_turns_the_image_upside_down(grid_face):
    flipped = grid_face.with_flipped_texture()
    assert np.array_equal(flipped.texture, grid_face.texture[::-1])
    assert flipped.landmarks == grid_face.landmarks and np.array_equal(flipped.uv, grid_face.uv)
    with pytest.raises(ValueError, match="no texture"):
        grid_face.without_texture().with_flipped_texture()


def test_texture_runs_down_when_v_falls_as_the_face_rises(grid_face):
    from core.face import Face, texture_runs_down

    assert not texture_runs_down(grid_face), "the grid's v rises with y"
    down = Face(grid_face.vertices, grid_face.triangles, uv=grid_face.uv * [1, -1] + [0, 1],
                texture=grid_face.texture)
    assert texture_runs_down(down)
    assert not texture_runs_down(Face(grid_face.vertices, grid_face.triangles)), "no uv"
    flat = Face(grid_face.vertices, grid_face.triangles, uv=np.full((grid_face.n_vertices, 2), 0.5))
    assert not texture_runs_down(flat), "no evidence, no flip"


def test_a_deferred_normals_kernel_leaves_numba_alone_until_warmed():
    """The window defers the compiled normals (core.normal_kernels) so its first frame does not wait
    for numba: until warm_up() the numpy path is used and numba is not even imported; afterwards the
    kernel gives the numpy path's normals. Run in a fresh interpreter (numba may be loaded here)."""
    code = (
        "import sys, numpy as np\n"
        "from core import lazy_numba, normal_kernels as k\n"
        "from core.face import VertexNormals\n"
        "lazy_numba.defer_until_warm()\n"
        "tri = np.array([[0, 1, 2], [0, 2, 3]]); v = np.array([[0., 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, .5]])\n"
        "before = VertexNormals(tri, 4)(v)\n"
        "print(k.kernel() is None, 'numba' in sys.modules)\n"
        "k.warm_up()\n"
        "print(k.kernel() is not None, np.allclose(k.kernel()(v, tri, np.empty_like(v)), before, atol=1e-12))\n")
    out = run_fresh_python(code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "False", "True", "True"]


def test_a_corrupt_numba_cache_is_rebuilt_with_a_note(tmp_path):
    """Numba raised on a damaged index file of its disk cache (the kernels' machine code): the cache
    files are removed, the kernel compiled afresh, and stderr says so; no crash."""
    import os

    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    env.pop("MIMICA_NO_NUMBA", None)
    code = "from core import normal_kernels as k; k.warm_up(); print(k.kernel() is not None)"

    def run():
        return run_fresh_python(code, env)

    first = run()
    assert first.returncode == 0 and first.stdout.split() == ["True"], first.stderr
    index = list(tmp_path.glob("**/normal_kernels.*.nbi"))
    assert index, "numba wrote no cache to damage"
    for path in index:
        path.write_bytes(b"garbage\n")
    second = run()
    assert second.returncode == 0 and second.stdout.split() == ["True"], second.stderr
    assert "cache of normal_kernels.py was unreadable" in second.stderr
    third = run()       # the cache was rewritten: quiet again
    assert third.returncode == 0 and "unreadable" not in third.stderr
