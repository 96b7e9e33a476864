"""A scan taken with the eyes shut: its lids stay closed at rest and open with the lid FAPs, cut along
the lid line, with the default face's eyeballs behind them (issue 15 item 3)."""

import numpy as np
import pytest

from core.layers.fap import tables
from core.layers.fap.closed_eyes import CLOSED_EYE_GAP, closed_eye_side, closed_lid_lines
from core.registration.correspondence import SurfaceRays


@pytest.fixture(scope="module")
def default_face():
    from core.default_face import load_default_face

    return load_default_face(full_head=False)


@pytest.fixture(scope="module")
def closed_face(default_face):
    """The default face with both upper lids at 1024 IRISD (fully closed), as a face of its own."""
    from core.cache import DiskCache
    from core.rig import FaceRig

    rig = FaceRig(default_face, cache=DiskCache())
    rig.set_faps({19: 1024.0, 20: 1024.0})
    return default_face.with_vertices(np.array(rig.vertices()))


@pytest.fixture(scope="module")
def closed_registration(closed_face):
    from core.registration.pipeline import register_scan
    from core.registration.virtual_scanner import scan_face

    scan = scan_face(closed_face, n_target=30_000, rng=np.random.default_rng(5)).face
    return register_scan(scan, scan.landmarks, template="mpeg4_80")


@pytest.fixture(scope="module")
def animated(closed_registration):
    from core.registration.scan_mouth import animated_scan

    return animated_scan(closed_registration)


def test_closed_eyes_are_told_from_open_ones(default_face, closed_face):
    assert closed_lid_lines(default_face) == []
    lines = closed_lid_lines(closed_face)
    assert sorted(line.eye for line in lines) == ["l", "r"]
    for line in lines:
        assert line.v[1] > 0.9                      # up, towards the brow (the face is upright)
        assert 20 < line.width < 40                 # corner to corner, mm
    # Above the lid line: upper lid; below: lower lid; far away (the chin): neither.
    left = next(line for line in lines if line.eye == "l")
    centre = left.start + left.u * left.s_mid + left.v * left.t_mid
    probe = np.array([centre + 3 * left.v, centre - 3 * left.v, closed_face.landmark_position("2.1")])
    above, inside = left.height(probe)
    assert inside[:2].all() and not inside[2]
    assert above[0] > 0 > above[1]
    sides = closed_eye_side(closed_face)
    assert set(np.unique(sides)) == {-1, 0, 1}


def test_irisd_of_a_closed_eye_is_that_of_an_open_eye_of_its_width(default_face, closed_face):
    def units(face):
        return tables.measure_fapu({n: face.landmark_position(n) for n in face.landmark_names})

    open_gap = np.mean([default_face.landmark_position(a)[1] - default_face.landmark_position(b)[1]
                        for a, b in (("3.1", "3.3"), ("3.2", "3.4"))])
    assert units(default_face)["IRISD"] * 1024 == pytest.approx(open_gap)   # open eyes: the lid gap, as before
    widths = [np.linalg.norm(closed_face.landmark_position(a) - closed_face.landmark_position(b))
              for a, b in (("3.7", "3.11"), ("3.12", "3.8"))]
    gaps = [closed_face.landmark_position(a)[1] - closed_face.landmark_position(b)[1]
            for a, b in (("3.1", "3.3"), ("3.2", "3.4"))]
    assert max(g / w for g, w in zip(gaps, widths)) < CLOSED_EYE_GAP
    assert units(closed_face)["IRISD"] * 1024 == pytest.approx(tables.OPEN_EYE_HEIGHT_PER_WIDTH * np.mean(widths))


def test_the_scan_is_cut_along_the_lid_lines_and_gets_eyeballs_behind_closed_lids(closed_registration, animated):
    face = animated.face
    assert {"eyeball_l", "eyeball_r"} <= set(face.parts)
    np.testing.assert_array_equal(animated.vertices(closed_registration.face.vertices)[:animated.n_scan],
                                  closed_registration.scan.vertices)          # rest is the scan itself
    # At rest the closed lid hides the eyeball: a ray from in front of the lid centre hits skin first.
    skin_ids = np.setdiff1d(np.arange(face.n_vertices), np.concatenate(list(face.parts.values())))
    hit_part = _first_part_hit(face, face.vertices, _lid_centres(face, face.vertices))
    assert hit_part == ["skin", "skin"]
    assert len(skin_ids) == animated.n_scan + animated.n_copies


@pytest.mark.parametrize("path", ["canonical rig carried to the scan", "rig on the animated scan"])
def test_the_lid_faps_open_a_closed_eye_onto_its_eyeball(closed_registration, animated, path):
    from core.layers.fap.fat import FapDeformer
    from core.rig import FaceRig

    face = animated.face
    values = {19: -300.0, 20: -300.0}               # open both upper lids as far as the sliders go
    if path == "canonical rig carried to the scan":
        rig = FaceRig(closed_registration.face)
        rig.set_faps(values)
        moved = animated.vertices(rig.vertices())
    else:   # the window's: a deformer on the shown face with the animated scan's own binding
        rig = FaceRig(face, FapDeformer(face, dense=animated.dense, binding=animated.binding()))
        rig.set_faps(values)
        moved = rig.vertices()
    rest_lids = face.landmark_positions(["3.1", "3.3", "3.2", "3.4"])
    lids = face.landmark_positions(["3.1", "3.3", "3.2", "3.4"], moved)
    rise = (lids - rest_lids)[:, 1]
    irisd = tables.measure_fapu({n: face.landmark_position(n) for n in face.landmark_names})["IRISD"]
    assert rise[[0, 2]] == pytest.approx(300 * irisd, rel=0.25)   # upper lids up by 300 IRISD units
    assert np.abs(rise[[1, 3]]).max() < 0.5                       # lower lids stay
    # Through the opening a ray now meets the eyeball, and no skin is stretched across it.
    assert _first_part_hit(face, moved, _lid_centres(face, moved)) == ["eyeball_l", "eyeball_r"]
    n_skin = animated.n_scan + animated.n_copies
    skin = face.triangles[(face.triangles < n_skin).all(axis=1)]
    growth = _edge_growth(face.vertices, moved, skin)
    assert growth.max() < 300 * irisd                             # no skin web spanning the opening


def _lid_centres(face, vertices) -> np.ndarray:
    """(2, 3) mm: the middle between each eye's upper and lower lid centres."""
    p = face.landmark_positions(["3.1", "3.3", "3.2", "3.4"], vertices)
    return np.array([(p[0] + p[1]) / 2, (p[2] + p[3]) / 2])


def _first_part_hit(face, vertices, targets) -> list[str]:
    """The part (or "skin") of the first triangle hit by a ray from 30 mm in front of each target."""
    rays = SurfaceRays(vertices, face.triangles)
    if rays.engine != "embree":
        pytest.skip("ray casting needs embreex")
    origins = targets + np.array([0.0, 0.0, 30.0])
    _, tri, hit = rays.first_hits(origins, np.tile([0.0, 0.0, -1.0], (len(targets), 1)))
    assert hit.all()
    names = []
    for t in tri:
        corner = face.triangles[t, 0]
        names.append(next((name for name, ids in face.parts.items() if corner in set(ids.tolist())), "skin"))
    return names


def _edge_growth(rest, moved, triangles) -> np.ndarray:
    def lengths(v):
        return np.linalg.norm(v[triangles] - v[np.roll(triangles, 1, axis=1)], axis=2)
    return (lengths(moved) - lengths(rest)).max(axis=1)


def test_a_closed_eye_closes_no_further(closed_registration, animated):
    """Its lids already meet: closing values (19-22 > 0) leave them where they are, as lid contact does
    for an open eye whose lids meet; the other eye's and opening values are unaffected."""
    from core.layers.fap.fat import FapDeformer, lid_contact
    from core.rig import FaceRig

    face = animated.face
    rig = FaceRig(face, FapDeformer(face, dense=animated.dense, binding=animated.binding()))
    rig.set_faps({19: 600.0, 21: 600.0, 20: 600.0, 22: 600.0})
    lids = ["3.1", "3.3", "3.2", "3.4"]
    np.testing.assert_allclose(face.landmark_positions(lids, rig.vertices()), face.landmark_positions(lids), atol=1e-6)
    values = np.zeros(68)
    values[[18, 20, 19, 21]] = (600.0, -200.0, 700.0, 700.0)
    out = lid_contact(values, closed=((19, 21),))                  # left eye closed, right open
    assert out[18] == 0.0 and out[20] == -200.0
    np.testing.assert_allclose(out[[19, 21]], 1024.0 / 1400.0 * 700.0)   # the open eye's lids meet


def test_a_closed_eyes_upper_lid_opens_it_fully_within_the_faces_own_range(default_face, animated):
    """The table's -300 IRISD lifts a closed lid a tenth of the eye's width (a sleepy slit): on a face
    whose eyes are closed at rest the upper-lid FAPs run 1024 further, to -1324 (an open eye's lids
    meet when their values add up to 1024), while the lower lids and an open-eyed face keep the
    table's range and refuse such values with the range in the message."""
    from core import parameters as P
    from core.cache import DiskCache
    from core.layers.fap.fat import FapDeformer
    from core.rig import FaceRig

    face = animated.face
    rig = FaceRig(face, FapDeformer(face, dense=animated.dense, binding=animated.binding()))
    for number in (19, 20):
        param = rig.describe(f"fap:{number}")
        assert (param.minimum, param.maximum) == (-1324.0, 1024.0)
        assert "closed at rest" in param.note
    for key in ("fap:21", "fap:22", "fap:3"):
        assert rig.describe(key) == P.describe(key)                     # the registry's
    with pytest.raises(P.ParameterError, match="outside its range -1324 to 1024"):
        rig.set_faps({19: -1400.0})
    with pytest.raises(P.ParameterError, match="outside its range -300 to 1024"):
        rig.set_values({"fap:21": -700.0})
    rig.set_values({"fap:19": -1024.0, "fap:20": -1024.0})
    moved = rig.vertices()
    lids = ["3.1", "3.3", "3.2", "3.4"]
    rest, now = face.landmark_positions(lids), face.landmark_positions(lids, moved)
    irisd = tables.measure_fapu({n: face.landmark_position(n) for n in face.landmark_names})["IRISD"]
    opening = (now[[0, 2], 1] - now[[1, 3], 1]) - (rest[[0, 2], 1] - rest[[1, 3], 1])
    assert opening == pytest.approx(1024 * irisd, rel=0.25)           # an open eye's height, about
    assert _first_part_hit(face, moved, _lid_centres(face, moved)) == ["eyeball_l", "eyeball_r"]
    n_skin = animated.n_scan + animated.n_copies
    skin = face.triangles[(face.triangles < n_skin).all(axis=1)]
    assert _edge_growth(face.vertices, moved, skin).max() < 1024 * irisd   # no skin web across the eye

    open_rig = FaceRig(default_face, cache=DiskCache())
    assert open_rig.describe("fap:19").minimum == -300.0 and not open_rig.describe("fap:19").note
    with pytest.raises(P.ParameterError, match="outside its range -300 to 1024"):
        open_rig.set_faps({19: -700.0})



def test_the_eyeball_stays_behind_the_scans_own_closed_lid(closed_registration, default_face):
    """Behind the scan's lid skin, not only the canonical face's, which spans a scan's lid crease: with
    a crease 3 mm deep pressed into the scan along the lid line, the eyeball placed by the canonical
    face alone reaches through it; placed by the scan too, every lid vertex is EYEBALL_BEHIND_MM outside."""
    from core.layers.fap.closed_eyes import closed_lid_lines
    from core.registration.scan_mouth import EYEBALL_BEHIND_MM, _eyeball_part, _lid_points
    from core.surface_query import TriangleSet

    canonical, scan = closed_registration.face, closed_registration.scan
    for line in closed_lid_lines(canonical):
        above, inside = line.height(scan.vertices)
        groove = np.where(inside, 3.0 * np.exp(-0.5 * (above / 0.8) ** 2), 0.0)
        creased = scan.with_vertices(scan.vertices - groove[:, None] * line.w)
        lid = _lid_points(creased, line)
        assert len(lid) > 100

        def smallest_gap(placed):
            vertices, triangles = placed[0], placed[1]
            closest, _, _ = TriangleSet(vertices, triangles).closest(lid)
            outward = np.einsum("kd,kd->k", lid - closest, lid - vertices.mean(axis=0))
            return (np.linalg.norm(lid - closest, axis=1) * np.sign(outward)).min()

        assert smallest_gap(_eyeball_part(canonical, default_face, line)) < 0          # through the crease
        assert smallest_gap(_eyeball_part(canonical, default_face, line, creased)) > EYEBALL_BEHIND_MM - 0.05


@pytest.fixture(scope="module")
def one_eye_shut(default_face):
    """The default face with only its right eye shut (upper lid at 1024 IRISD), scanned and registered."""
    from core.cache import DiskCache
    from core.registration.pipeline import register_scan
    from core.registration.virtual_scanner import scan_face
    from core.rig import FaceRig

    rig = FaceRig(default_face, cache=DiskCache())
    rig.set_faps({20: 1024.0})
    face = default_face.with_vertices(np.array(rig.vertices()))
    scan = scan_face(face, n_target=30_000, rng=np.random.default_rng(5)).face
    return register_scan(scan, scan.landmarks, template="mpeg4_80")


def test_open_eyes_get_an_eyeball_behind_their_own_hidden_eye_surface(one_eye_shut):
    """An open eye's own scanned surface is hidden and the donor's eyeball sits behind the opening
    (bound to the template's eye covers, which the FAPs do not move, the scan's eye stood still while
    the lids closed onto it); the shut eye is cut along its lid line as before. Both eyeballs turn with
    gaze, and the open eye's lid closes over its eyeball at 1024 IRISD (with the scan's own eye surface
    in the opening, 218 lid crossing pairs and 167 folded triangles; now about a tenth of that)."""
    from core.layers.fap.fat import FapDeformer
    from core.mesh_quality import FaceQualityProbe
    from core.registration.scan_mouth import animated_scan
    from core.rig import FaceRig

    animated = animated_scan(one_eye_shut)
    face = animated.face
    assert {"eyeball_l", "eyeball_r"} <= set(face.parts)
    # Through the open left eye a ray meets the eyeball; the shut right eye still hides its own.
    assert _first_part_hit(face, face.vertices, _lid_centres(face, face.vertices)) == ["eyeball_l", "skin"]
    deformer = FapDeformer(face, dense=animated.dense, binding=animated.binding())
    assert {23, 24, 25, 26} <= set(deformer.animated_faps)
    rig = FaceRig(face, deformer)
    probe = FaceQualityProbe(face)
    assert probe.measure(face.vertices, eyes=True).eye_openness["left"] > 0.5
    rig.set_fap(19, 1024.0)
    closed = probe.measure(rig.vertices(), eyes=True)
    assert closed.eye_openness["left"] < 0.02
    assert closed.lid_intersections <= 30 and closed.folded_triangles <= 20


def test_one_eyeball_has_its_lids_guarded(default_face, one_eye_shut):
    """A face with one eyeball (here: the donor offers only the right one, for the shut right eye)
    keeps that eye's lid skin outside it as the lid FAPs and the expressions open it and as the brows
    come down onto it (the guard once waited for both eyeballs: the lowered brows crossed it 42 times);
    gaze, which turns both eyes, stays off."""
    from core.face import Face
    from core.layers.fap.fat import FapDeformer
    from core.mesh_quality import FaceQualityProbe
    from core.registration.scan_mouth import animated_scan
    from core.rig import FaceRig

    d = default_face
    donor = Face(d.vertices, d.triangles, uv=d.uv, texture=d.texture, landmarks=d.landmarks,
                 parts={name: ids for name, ids in d.parts.items() if name != "eyeball_l"})
    animated = animated_scan(one_eye_shut, donor)
    face = animated.face
    assert "eyeball_r" in face.parts and "eyeball_l" not in face.parts
    deformer = FapDeformer(face, dense=animated.dense, binding=animated.binding())
    assert [guard.faps for guard in deformer._lid_guards] == [(20, 22, 42)]
    assert not {23, 24, 25, 26} & set(deformer.animated_faps)
    rig = FaceRig(face, deformer)
    probe = FaceQualityProbe(face)
    for pose in ({20: -300.0}, {32: -400.0, 34: -400.0, 36: -400.0}, "surprise", "fear"):
        rig.reset()
        rig.set_faps(pose) if isinstance(pose, dict) else rig.set_expression(pose, 1.0)
        assert probe.measure(rig.vertices()).lid_intersections == 0, pose
