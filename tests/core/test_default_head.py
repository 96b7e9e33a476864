"""The default face's full head: the front of the face extended by a head shell and ears, stitched
without a seam that could open, and the front-only face kept for the scan-like uses."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from core.default_face import FaceLayout, FaceParameters, generate_face, load_default_face
from core.default_face.head import fair_radially, hair_mask, outer_boundary_loop
from core.face import coincident_skin_vertices
from tests.core.test_default_face import skin_mask

MAX_EXTRA_TRIANGLES = 20_000   # the software renderer's cost follows the triangle count


@pytest.fixture(scope="module")
def front():
    return load_default_face(full_head=False)


@pytest.fixture(scope="module")
def head():
    return load_default_face()


def seam_pairs(head, n_front: int) -> tuple[np.ndarray, np.ndarray]:
    """(front rim vertices, their shell copies): appended vertices at exactly a front vertex's position."""
    dist, nearest = cKDTree(head.vertices[:n_front]).query(head.vertices[n_front:], distance_upper_bound=1e-9)
    copies = np.nonzero(np.isfinite(dist))[0]
    return nearest[copies], copies + n_front


def front_vertex_count(head) -> int:
    """How many of the head's first vertices are its front (skin, eyeballs, mouth; the shell follows)."""
    return int(head.parts["teeth_lower"].max()) + 1


def skin_rim(face) -> np.ndarray:
    """The skin's outer boundary loop (vertex ids)."""
    return outer_boundary_loop(face.triangles[skin_mask(face)[face.triangles].all(axis=1)])


def origin_in_front(head, front) -> tuple[np.ndarray, np.ndarray]:
    """(index of the front-only face's vertex each of the head's front vertices was made from, -1 if
    none; whether it is exactly in place). The head moves its rim a little and opens the nostrils
    straight up (in y): matched in place, then on (x, z) exactly, then within 1 mm in (x, y)."""
    n = front_vertex_count(head)
    dist, origin = cKDTree(front.vertices).query(head.vertices[:n])
    exact = dist == 0.0
    xz_dist, xz_origin = cKDTree(front.vertices[:, [0, 2]]).query(head.vertices[:n][:, [0, 2]])
    take = ~exact & (xz_dist == 0.0)
    origin[take] = xz_origin[take]
    xy_dist, xy_origin = cKDTree(front.vertices[:, :2]).query(head.vertices[:n][:, :2])
    rest = ~exact & ~take
    origin[rest] = np.where(xy_dist[rest] < 1.0, xy_origin[rest], -1)
    return origin, exact


def nostril_rise(head, front) -> tuple[np.ndarray, np.ndarray]:
    """(how far each of the head's front vertices rose in y from the front-only face's, mm (0 on the
    rim and for vertices of no origin); origin_in_front's indices)."""
    origin, exact = origin_in_front(head, front)
    n = len(origin)
    rim = skin_rim(head)
    rise = np.where(origin >= 0, head.vertices[:n, 1] - front.vertices[np.maximum(origin, 0), 1], 0.0)
    rise[rim[rim < n]] = 0.0
    return rise, origin


def welded_boundary_loops(face, pairs) -> int:
    """Number of boundary loops of the skin (no named part) once each shell copy is welded to its rim vertex."""
    rim, copies = pairs
    lut = np.arange(face.n_vertices)
    lut[copies] = rim
    in_part = np.zeros(face.n_vertices, bool)
    for idx in face.parts.values():
        in_part[idx] = True
    tri = lut[face.triangles[~in_part[face.triangles].any(axis=1)]]
    directed = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    n = face.n_vertices
    key, reverse = directed[:, 0] * n + directed[:, 1], directed[:, 1] * n + directed[:, 0]
    boundary = directed[~np.isin(key, reverse)]
    nxt = dict(zip(boundary[:, 0].tolist(), boundary[:, 1].tolist()))
    seen, loops = set(), 0
    for start in nxt:
        if start in seen:
            continue
        loops += 1
        v = start
        while v not in seen:
            seen.add(v)
            v = nxt[v]
    return loops


def test_the_heads_front_is_the_scan_front_short_of_its_unseen_rim(front, head):
    n = front_vertex_count(head)
    assert set(head.parts) == set(front.parts) | {"ear_l", "ear_r"}
    for name in front.parts:     # eyeballs, mouth cavity and teeth: the same vertices, in place
        assert np.array_equal(head.vertices[head.parts[name]], front.vertices[front.parts[name]])
    assert head.landmarks.keys() == front.landmarks.keys()
    names = list(front.landmarks)
    assert np.allclose(head.landmark_positions(names), front.landmark_positions(names), atol=1e-9)
    # Every skin vertex is one of the front's, in place, but the outer rim (smoothed, by little in
    # x and y) and the nostrils (opened straight up).
    origin, exact = origin_in_front(head, front)
    skin = skin_mask(head)[:n]
    rim = skin_rim(head)
    on_rim = np.zeros(len(head.vertices), bool)
    on_rim[rim] = True
    moved = np.nonzero(skin & ~exact)[0]
    assert np.all(origin[skin] >= 0)
    assert np.abs(head.vertices[moved[on_rim[moved]], :2] - front.vertices[origin[moved[on_rim[moved]]], :2]).max() < 1.0
    nostril = moved[~on_rim[moved]]
    step = head.vertices[nostril] - front.vertices[origin[nostril]]
    assert len(nostril) > 60 and np.all(step[:, [0, 2]] == 0) and np.all(step[:, 1] > 0)
    # What the head leaves out of the front: skin along the outer rim that faces away from the view
    # axis (the shell covers it), a few rows; never a feature point's triangle.
    kept = np.zeros(front.n_vertices, bool)
    kept[origin[skin]] = True
    dropped = np.nonzero(~kept & skin_mask(front))[0]
    twin = cKDTree(front.vertices[kept]).query(front.vertices[dropped])[0] == 0.0   # the mouth seam's pairs
    dropped = dropped[~twin]
    front_rim = skin_rim(front)
    from_rim = cKDTree(front.vertices[front_rim, :2]).query(front.vertices[dropped, :2])[0]
    assert 300 < len(dropped) < 0.05 * front.n_vertices
    assert from_rim.max() < 8.0
    assert np.median(np.abs(front.vertex_normals[dropped, 2])) < np.cos(np.radians(75.0))
    held = front.triangles[[point.triangle for point in front.landmarks.values()]]
    assert not np.isin(held, dropped).any()
    assert head.texture.shape[1] > front.texture.shape[1]
    assert head.uv.min() >= 0 and head.uv.max() <= 1


def test_triangle_budget(front, head):
    extra = head.n_triangles - front.n_triangles
    assert 4_000 < extra <= MAX_EXTRA_TRIANGLES   # the shell's; less the rim the head's front leaves out


def test_the_skin_is_closed_but_for_the_eyes_and_the_mouth(front, head):
    pairs = seam_pairs(head, front_vertex_count(head))
    assert len(pairs[0]) > 500
    # Front only: the outer rim, two eye openings, the mouth. With the head: no outer rim left.
    assert welded_boundary_loops(front, (np.zeros(0, int), np.zeros(0, int))) == 4
    assert welded_boundary_loops(head, pairs) == 3
    # The ears are closed surfaces.
    for name in ("ear_l", "ear_r"):
        idx = head.parts[name]
        tri = head.triangles[np.isin(head.triangles, idx).all(axis=1)]
        edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        assert (counts == 2).all()


def test_head_proportions(head, front):
    lo, hi = head.bounds
    size = hi - lo
    chin = front.landmark_position("2.1")[1]
    above_chin = head.vertices[head.vertices[:, 1] > chin]
    assert 140 < np.ptp(above_chin[:, 0]) < 200        # ear to ear
    assert 190 < size[2] < 240        # nose tip to the back of the head
    top = hi[1] - chin
    assert 200 < top < 260            # vertex to menton (adult: about 230 mm)
    below = front.bounds[0][1] - lo[1]
    assert 60 < below < 120           # the neck and the shoulders' start below the chin


def half_width_at(face, y: float, band: float = 2.0) -> float:
    """Half the x extent of the skin (no eyes, teeth or ears) within ``band`` mm of height y."""
    in_part = np.zeros(face.n_vertices, bool)
    for idx in face.parts.values():
        in_part[idx] = True
    v = face.vertices[~in_part]
    return float(np.abs(v[np.abs(v[:, 1] - y) < band, 0]).max())


@pytest.mark.parametrize("seed", [None, 3, 11])
def test_the_neck_is_narrower_than_the_jaw_and_flares_into_the_shoulders(seed, head):
    """Not a column: the neck's outline steps in under the jaw and widens into the trapezius slope
    down to the bottom cap (before: as wide as the jaw, flaring 22 % at the bottom)."""
    from core.default_face.head import HeadModel

    params = FaceParameters() if seed is None else FaceParameters.random(np.random.default_rng(seed), spread=0.8)
    face = head if seed is None else generate_face(params)
    layout = FaceLayout.from_parameters(params)
    model = HeadModel(layout)
    jaw = half_width_at(face, layout.stomion_y - 10.0)          # the jaw below the mouth corners
    neck = half_width_at(face, model.neck_base_y + 3.0)          # the neck just above its base
    shoulders = half_width_at(face, model.neck_bottom_y + 10.0)  # the shoulders' start above the cap
    assert neck < 0.85 * jaw
    assert shoulders > 2.2 * neck
    # The slope from the neck to the shoulders is a trapezius, not a step: 10-45 degrees from level.
    dy = (model.neck_base_y - 3.0) - (model.neck_base_y - 0.9 * 48.0 * model.scale[1])
    dx = half_width_at(face, model.neck_base_y - 0.9 * 48.0 * model.scale[1]) - half_width_at(face, model.neck_base_y - 3.0)
    assert 10.0 < np.degrees(np.arctan2(dy, dx)) < 45.0


def test_the_flare_is_a_bijection():
    from core.default_face.head import HeadModel

    model = HeadModel(FaceLayout.from_parameters(FaceParameters()))
    p = np.random.default_rng(0).uniform([-150, -200, -250], [150, 50, 0], (5000, 3))
    assert np.allclose(model.unwarp(model.warp(p)), p)
    above = p[p[:, 1] > model.neck_base_y]
    assert np.array_equal(model.warp(above), above)


def test_radial_fairing_restores_a_sphere_and_keeps_directions():
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=50.0)
    v, t = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    free = v[:, 2] > 20.0                                   # a cap, bumped radially at random
    bumped = v.copy()
    bumped[free] *= np.random.default_rng(0).uniform(0.8, 1.2, free.sum())[:, None]
    faired = fair_radially(bumped, t, free, np.zeros(3))
    assert np.abs(np.linalg.norm(faired, axis=1) - 50.0).max() < 1e-6      # the constant radius is the fill
    assert np.allclose(faired[~free], v[~free])
    unit = faired / np.linalg.norm(faired, axis=1, keepdims=True)
    assert np.allclose(unit, v / 50.0)                      # only along the radius


def test_the_shell_continues_the_face_slope_across_the_seam(head):
    """Where the shell meets the front of the face their normals agree (no crease along the seam:
    before the shell was faired, 1 seam vertex in 10 turned by more than 65 degrees)."""
    members, groups = coincident_skin_vertices(head)
    order = np.argsort(groups, kind="stable")
    a, b = members[order][0::2], members[order][1::2]
    assert len(a) > 500                                     # the rim seam is found and welded
    angle = np.degrees(np.arccos(np.clip((head.vertex_normals[a] * head.vertex_normals[b]).sum(axis=1), -1, 1)))
    assert np.median(angle) < 12.0 and np.percentile(angle, 90) < 30.0


def test_the_shell_faces_outward(head, front):
    """Every shell triangle faces away from the head's centre once the shoulders' flare is undone
    (the star-shaped shell the flare moves); the flare keeps each triangle's orientation."""
    from core.default_face.head import HeadModel

    model = HeadModel(FaceLayout.from_parameters(FaceParameters()))
    n = front_vertex_count(head)
    shell = head.triangles[(head.triangles >= n).all(axis=1)]
    shell = shell[~np.isin(shell, head.parts["ear_l"]).any(axis=1) & ~np.isin(shell, head.parts["ear_r"]).any(axis=1)]
    corners = model.unwarp(head.vertices[shell].reshape(-1, 3)).reshape(-1, 3, 3)
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    outward = (normal * (corners.mean(axis=1) - model.centre)).sum(axis=1)
    assert (outward > 0).mean() > 0.99
    # No sliver left on the neck and shoulders (the throat grazed from the centre gave them).
    low = corners.mean(axis=1)[:, 1] < front.landmark_position("2.1")[1] - 10.0
    p = head.vertices[shell[low]]
    edges = np.linalg.norm(p[:, [1, 2, 0]] - p, axis=2)
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    quality = 4 * np.sqrt(3) * area / (edges ** 2).sum(axis=1)      # 1 = equilateral
    assert low.sum() > 2000 and np.percentile(quality, 1) > 0.3 and edges.max() < 12.0
    for name in ("ear_l", "ear_r"):
        idx = head.parts[name]
        corners = head.vertices[head.triangles[np.isin(head.triangles, idx).all(axis=1)]]
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        away = (normal * (corners.mean(axis=1) - head.vertices[idx].mean(axis=0))).sum(axis=1)
        assert (away > 0).mean() > 0.7     # a thin, curved shell: most triangles face away from its middle


def test_hair_covers_the_top_and_back_but_not_the_face_or_neck():
    layout = FaceLayout.from_parameters(FaceParameters())
    points = np.array([[0, 150, -110], [0, 60, -215], [70, 90, -90],      # crown, back, temple above the ear
                       [0, 0, 0], [0, -150, -60], [0, -150, -170]])       # nose, throat, nape of the neck
    assert hair_mask(layout, points) == pytest.approx([1, 1, 1, 0, 0, 0], abs=0.01)


def test_seam_never_opens_at_any_slider_end_or_preset(default_rig, front):
    """Every FAP at both ends of its range, every expression and viseme at 100 %, every muscle preset:
    each shell seam vertex stays exactly on the front's rim vertex it copies."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from face_quality import fap_poses, muscle_poses, preset_poses

    rig = default_rig
    rim, copies = seam_pairs(rig.face, front_vertex_count(rig.face))
    assert len(rim) > 500
    jaw_moved = False
    try:
        poses = list(fap_poses(rig)) + list(preset_poses(rig, mixes=False)) + list(muscle_poses(rig))
        assert len(poses) > 100
        for _family, label, apply, _eyes in poses:
            rig.reset()
            apply(rig)
            x = np.asarray(rig.vertices())
            gap = np.linalg.norm(x[copies] - x[rim], axis=1).max()
            assert gap == 0.0, f"{label}: the seam opens by {gap:.3g} mm"
            if label.startswith("fap 3 "):
                jaw_moved = np.linalg.norm(x[copies] - rig.face.vertices[copies], axis=1).max() > 2.0
    finally:
        rig.remove_layer("muscles")
        rig.reset()
    assert jaw_moved   # the jaw takes the shell under the chin with it


def test_the_shell_stays_still_away_from_the_jaw(default_rig, front):
    rig = default_rig
    n = front_vertex_count(rig.face)
    ears = np.concatenate([rig.face.parts["ear_l"], rig.face.parts["ear_r"]])
    try:
        rig.reset()
        rig.set_fap(3, 1400)   # the jaw wide open
        moved = np.linalg.norm(np.asarray(rig.vertices()) - rig.face.vertices, axis=1)
        shell = np.arange(n, rig.face.n_vertices)
        above_eyes = shell[rig.face.vertices[shell, 1] > 33.0]
        assert moved[above_eyes].max() < 0.05
        assert moved[ears].max() == 0.0
        under_chin = shell[(rig.face.vertices[shell, 1] < -75.0) & (rig.face.vertices[shell, 2] > -90.0)]
        assert moved[under_chin].max() > 3.0
        rig.reset()
        rig.set_fap(49, 20000)   # head yaw: everything turns, ears included
        moved = np.linalg.norm(np.asarray(rig.vertices()) - rig.face.vertices, axis=1)
        assert moved[ears].min() > 1.0
    finally:
        rig.reset()


def test_a_changed_face_gets_its_own_fap_cache_key(front, head):
    from core.layers.fap.fat import deformer_key

    assert deformer_key(front) != deformer_key(head)


def test_registration_and_scans_keep_the_front_only_face(front):
    from core.registration.pipeline import default_model
    from core.registration.synthetic import identity_face

    assert default_model().n_vertices == front.n_vertices
    assert identity_face(0).n_vertices == front.n_vertices
    other = identity_face(1)
    assert "ear_l" not in other.parts and other.texture.shape == (480, 640, 3)


def test_generated_head_of_another_identity():
    face = generate_face(FaceParameters.random(np.random.default_rng(3), spread=0.8))
    front = generate_face(FaceParameters.random(np.random.default_rng(3), spread=0.8), full_head=False)
    assert face.n_triangles - front.n_triangles <= MAX_EXTRA_TRIANGLES
    pairs = seam_pairs(face, front_vertex_count(face))
    assert welded_boundary_loops(face, pairs) == 3


def test_the_nostrils_are_pockets_in_the_nose_darker_inside(front, head):
    """The full head's nostrils: two pockets, as deep as ``POCKET_DEPTH`` under their roof, mirror
    images, inside the nose (behind its skin), their texture dark (the front-only face keeps the
    scanner's shallow dents and its painted spots)."""
    from core.default_face.nostrils import POCKET_DEPTH, pocket_clearance
    from core.default_face.shape import FaceShape

    layout = FaceLayout.from_parameters(FaceParameters())
    rise, origin = nostril_rise(head, front)
    pocket = np.nonzero(rise > 0)[0]
    for side in (1, -1):
        one = pocket[np.sign(head.vertices[pocket, 0]) == side]
        assert len(one) > 30
        assert rise[one].max() == pytest.approx(POCKET_DEPTH, abs=0.3)
        p = front.vertices[origin[one]]
        assert layout.subnasale_y < p[:, 1].min() and p[:, 1].max() < layout.nose_tip_y
        assert 2.0 < np.abs(p[:, 0]).min() and np.abs(p[:, 0]).max() < layout.alar_half_width
    front_pocket = origin[pocket]
    mirrored = front.vertices[front_pocket] * [-1, 1, 1]
    dist, twin = cKDTree(front.vertices[front_pocket]).query(mirrored)
    assert dist.max() < 1e-6 and np.allclose(rise[pocket[twin]], rise[pocket], atol=1e-6)
    deep = pocket[rise[pocket] > 1.0]
    assert pocket_clearance(FaceShape(layout), head.vertices[deep]).min() > 0.4
    # Texture: the pocket's deep vertices are dark, the nose tip is skin.
    def luminance(uv):
        h, w, _ = head.texture.shape
        px = head.texture[((1 - uv[:, 1]) * h).astype(int).clip(0, h - 1), (uv[:, 0] * w).astype(int).clip(0, w - 1)]
        return px.astype(float).mean(axis=1)
    tip = np.argmin(np.linalg.norm(head.vertices - head.landmark_position("9.3"), axis=1))
    assert luminance(head.uv[deep]).max() < 0.5 * luminance(head.uv[[tip]])[0]


def test_generated_identities_open_their_nostrils():
    for seed in (3, 11):
        params = FaceParameters.random(np.random.default_rng(seed), spread=0.8)
        face, front = generate_face(params), generate_face(params, full_head=False)
        rise, _ = nostril_rise(face, front)
        assert (rise > 2.0).sum() > 20
