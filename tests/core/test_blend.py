"""Expression blends (issue 16): libraries, the blend layer, transfer, caricature, correctives, files.

Known answers on faces built in code (a bumpy grid patch as "a person"; poses are that patch plus
known local displacements, then moved rigidly the way a scanner would see them)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core import parameters as P
from core.formats.blend_library import LibraryFileError, read_library, write_library
from core.layers.blend.caricature import caricature, mean_face
from core.layers.blend.corrective import Corrective, CorrectiveLayer, fit_faps
from core.layers.blend.layer import BlendLayer
from core.layers.blend.library import ExpressionLibrary, LibraryError, build_library, rigid_align
from core.layers.blend.transfer import DeformationTransfer, LocalAffineTransfer, transfer_bbox, transfer_library
from core.registration.icp import rotation_about_axis
from tests.core.conftest import make_grid_face, without_surface_guard

SCALE_MM = 200.0


def _rigid(points, angle_deg=7.0, axis=(0.3, 1.0, 0.2), shift=(4.0, -2.0, 9.0)):
    R = rotation_about_axis(axis, angle_deg)
    return points @ R.T + np.asarray(shift), R


@pytest.fixture(scope="module")
def person():
    """(face, {pose: true local displacement (n, 3)}): two poses moving separate patches."""
    face = make_grid_face(nx=24, ny=20, size_mm=SCALE_MM)
    v = face.vertices
    # compact bumps: (1 - d²/r²)³ inside radius r, exactly 0 outside (the rest of the face is still)
    bump = lambda c, r: np.clip(1 - np.sum((v[:, :2] - c) ** 2, axis=1) / (r * r), 0, None) ** 3   # noqa: E731
    smile = np.column_stack([6.0 * bump((40.0, -40.0), 35.0), 4.0 * bump((40.0, -40.0), 35.0), 0 * v[:, 0]])
    brow = np.column_stack([0 * v[:, 0], 5.0 * bump((-50.0, 60.0), 30.0), 2.0 * bump((-50.0, 60.0), 30.0)])
    return face, {"smile": smile, "brow_up": brow}


@pytest.fixture(scope="module")
def library(person):
    face, truth = person
    poses = {name: _rigid(face.vertices + d, angle_deg=5.0 + i)[0] for i, (name, d) in enumerate(truth.items())}
    return build_library(face, poses, base="grid person")


# ------------------------------------------------------------------ libraries and blending
def test_zero_weights_give_the_rest_exactly(library):
    np.testing.assert_array_equal(library.blend({}), library.rest)
    np.testing.assert_array_equal(library.blend(np.zeros(len(library.names))), library.rest)


def test_weight_one_reproduces_the_aligned_pose(person, library):
    face, truth = person
    for name, d in truth.items():
        # the scanner moved the pose rigidly; alignment onto the neutral undoes it exactly
        np.testing.assert_allclose(library.blend({name: 1.0}), face.vertices + d, atol=1e-6 * SCALE_MM)
    both = library.blend({"smile": 0.5, "brow_up": 2.0})
    np.testing.assert_allclose(both, face.vertices + 0.5 * truth["smile"] + 2.0 * truth["brow_up"], atol=1e-6 * SCALE_MM)


def test_rigid_align_recovers_a_known_motion(person):
    face, _ = person
    moved, R = _rigid(face.vertices)
    aligned, R_back, _ = rigid_align(moved, face.vertices)
    np.testing.assert_allclose(aligned, face.vertices, atol=1e-9)
    np.testing.assert_allclose(R_back @ R, np.eye(3), atol=1e-12)


def test_bad_libraries_are_refused_with_a_reason(library):
    with pytest.raises(LibraryError, match="pose names"):
        library.replace(names=("Smile", "brow_up"))
    with pytest.raises(LibraryError, match="'neutral' is the library's rest"):
        library.replace(names=("neutral", "brow_up"))
    with pytest.raises(LibraryError, match="NaN"):
        library.replace(displacements=np.full(library.displacements.shape, np.nan))
    with pytest.raises(LibraryError, match="no pose 'frown'"):
        library.blend({"frown": 1.0})


# ------------------------------------------------------------------ the rig layer
def test_blend_layer_parameters_offsets_and_errors(person, library):
    face, truth = person
    layer = BlendLayer(face, library)
    assert layer.parameters() == ("blend:smile", "blend:brow_up")
    assert layer.offset(face.vertices) is None
    layer.set_values({"blend:smile": 100.0})
    np.testing.assert_allclose(layer.offset(face.vertices), truth["smile"], atol=1e-6 * SCALE_MM)
    with pytest.raises(P.ParameterError, match="outside its range -50 to 200 %"):
        layer.set_values({"blend:smile": 250.0})
    with pytest.raises(P.ParameterError, match="not a pose of this face's expression library; its poses are smile, brow_up"):
        layer.set_values({"blend:frown": 10.0})
    assert layer.value("blend:smile") == 100.0                      # nothing changed
    other = make_grid_face(nx=5, ny=5)
    with pytest.raises(LibraryError, match="register the face"):
        BlendLayer(other, library)


def test_blend_layer_maps_through_a_correspondence(person, library):
    import scipy.sparse

    face, truth = person
    n = face.n_vertices
    # a face with the library's vertices twice (e.g. a finer mesh bound to the canonical one)
    M = scipy.sparse.vstack([scipy.sparse.identity(n), scipy.sparse.identity(n)]).tocsr()
    layer = BlendLayer(np.zeros((2 * n, 3)), library, correspondence=M)
    layer.set_values({"blend:brow_up": 50.0})
    off = layer.offset(None)
    np.testing.assert_allclose(off[:n], 0.5 * truth["brow_up"], atol=1e-6 * SCALE_MM)
    np.testing.assert_array_equal(off[n:], off[:n])


def test_blend_key_through_the_rig_snapshot_restore_and_copy(default_rig, monkeypatch):
    rig = default_rig
    # Random millimetre offsets break the skin everywhere: the surface guard would smooth them (not
    # additive); this checks how the layers compose, so it is left out.
    without_surface_guard(monkeypatch, rig)
    rig.reset()
    rest = rig.face.vertices
    rng = np.random.default_rng(3)
    lib = ExpressionLibrary(rest, ("joy", "blink"), rng.normal(0, 1.0, (2, len(rest), 3)), base="default face")
    try:
        rig.add_layer(BlendLayer(rig.face, lib))
        assert "blend:joy" in rig.parameters()
        base = np.array(rig.vertices())
        rig.set_values({"blend:joy": 80.0, "fap:3": 100.0})
        snap = rig.snapshot()
        posed = np.array(rig.vertices())
        np.testing.assert_allclose(posed - rig.copy().vertices(), 0, atol=1e-12)   # an export's copy agrees
        rig.set_values({"fap:3": 100.0, "blend:joy": 0.0})
        free = ~rig.deformer.finish_zone()       # random offsets press the lips and push lids into the eyeballs
        np.testing.assert_allclose((posed - np.array(rig.vertices()))[free], 0.8 * lib.displacements[0][free], atol=1e-9)
        rig.restore(snap)
        assert rig.value("blend:joy") == 80.0
        np.testing.assert_array_equal(rig.vertices(), posed)
        rig.reset()
        np.testing.assert_array_equal(rig.vertices(), base)
    finally:
        rig.remove_layer("blend")
        rig.reset()


def test_registry_knows_blend_and_caricature_keys():
    assert P.key_of("blend:Joy") == "blend:joy"
    assert P.describe("caricature").minimum == -100.0 and P.describe("caricature").maximum == 200.0
    assert P.describe("blend:joy").unit == "%"
    with pytest.raises(P.ParameterError, match="blend:neutral"):
        P.key_of("blend:neutral")
    with pytest.raises(P.ParameterError, match="outside its range -100 to 200"):
        P.check_value("caricature", -150)


# ------------------------------------------------------------------ transfer
def test_transfer_to_the_base_itself_is_the_identity(library, person):
    face, _ = person
    np.testing.assert_allclose(transfer_bbox(library.rest, library.displacements, library.rest),
                               library.displacements, atol=1e-12)
    dt = DeformationTransfer(library.rest, library.rest, face.triangles)
    np.testing.assert_allclose(dt.transfer(library.displacements), library.displacements, atol=1e-8)
    la = LocalAffineTransfer(library.rest, library.rest)
    np.testing.assert_allclose(la.transfer(library.displacements), library.displacements, atol=1e-8)
    out = transfer_library(library, face, method="deformation")
    assert out.transfer == "deformation" and "deformation" in out.base


def test_transfer_to_a_scaled_moved_copy_scales_and_rotates(library, person):
    face, _ = person
    model, R = _rigid(1.25 * library.rest, angle_deg=20.0)
    expected = 1.25 * library.displacements @ R.T
    np.testing.assert_allclose(transfer_bbox(library.rest, library.displacements, model), expected, atol=1e-8)
    dt = DeformationTransfer(library.rest, model, face.triangles)
    np.testing.assert_allclose(dt.transfer(library.displacements), expected, atol=1e-6)
    with pytest.raises(LibraryError, match="unknown transfer method"):
        transfer_library(library, model, face.triangles, method="magic")


# ------------------------------------------------------------------ caricature
def test_caricature_zero_is_the_face_and_minus_100_the_mean(person):
    face, truth = person
    faces = [face.vertices, face.vertices + truth["smile"], _rigid(face.vertices + truth["brow_up"])[0]]
    mean = mean_face(faces)
    np.testing.assert_allclose(mean_face([faces[0], _rigid(faces[0])[0]]), faces[0], atol=1e-9)
    f = faces[1]
    np.testing.assert_array_equal(caricature(f, mean, 0.0), f)
    np.testing.assert_allclose(caricature(f, mean, -1.0), rigid_align(mean, f, robust=False)[0], atol=1e-9)
    with pytest.raises(LibraryError, match="−100 % … \\+200 %"):
        caricature(f, mean, 2.5)


def test_caricature_parameter_of_the_layer(person, library):
    face, truth = person
    mean = face.vertices - np.column_stack([0 * truth["smile"][:, 0], truth["smile"][:, :2]])[:, [1, 2, 0]]
    lib = library.replace(mean=mean)
    layer = BlendLayer(face, lib)
    assert "caricature" in layer.parameters()
    layer.set_values({"caricature": -100.0})
    np.testing.assert_allclose(face.vertices + layer.offset(face.vertices),
                               rigid_align(mean, face.vertices, robust=False)[0], atol=1e-9)


# ------------------------------------------------------------------ files
def test_library_files_round_trip(tmp_path, library):
    lib = library.replace(mean=library.rest + 1.0, template="custom")
    path = write_library(lib, tmp_path / "person.json")
    back = read_library(path)
    assert back.names == lib.names and back.template == "custom" and back.base == "grid person"
    np.testing.assert_allclose(back.rest, lib.rest, atol=1e-4)
    np.testing.assert_allclose(back.displacements, lib.displacements, atol=1e-5)
    np.testing.assert_allclose(back.mean, lib.mean, atol=1e-4)
    write_library(back, tmp_path / "again.json")
    assert (tmp_path / "again.npz").read_bytes() == (tmp_path / "person.npz").read_bytes()


def _damaged(tmp_path, library, *, header=None, arrays=None):
    path = write_library(library, tmp_path / "lib.json")
    if header is not None:
        head = json.loads(path.read_text())
        head.update(header)
        path.write_text(json.dumps(head))
    if arrays is not None:
        npz = tmp_path / "lib.npz"
        with np.load(npz) as data:
            a = {k: data[k] for k in data.files}
        a.update(arrays)
        np.savez_compressed(npz, **a)
    return path


@pytest.mark.parametrize("header, arrays, field", [
    ({"template": "mpeg4_80"}, None, "vertex_count"),          # other template: its faces have 4560 vertices
    ({"template": "nosuch"}, None, "template"),
    ({"vertex_count": 17}, None, "rest"),                       # arrays do not match the header
    ({"version": 9}, None, "version"),
    ({"poses": ["smile", "Brow"]}, None, "poses"),
    ({"format": "something"}, None, "format"),
    ({"units": "cm"}, None, "units"),
    ({"arrays": "../elsewhere.npz"}, None, "arrays"),
    (None, {"displacements": "nan"}, "displacements"),
    (None, {"rest": "short"}, "rest"),
])
def test_malformed_library_files_name_file_and_field(tmp_path, library, header, arrays, field):
    if arrays is not None:
        key, kind = next(iter(arrays.items()))
        a = getattr(library, key).astype(np.float32).copy()
        if kind == "nan":
            a.reshape(-1)[5] = np.nan
        else:
            a = a[:-1]
        arrays = {key: a}
    path = _damaged(tmp_path, library, header=header, arrays=arrays)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(LibraryFileError) as err:
        read_library(path)
    assert f"'{field}'" in str(err.value) and "lib." in str(err.value)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before     # nothing changed


def test_mismatched_library_for_a_face_says_what_to_do(tmp_path, library):
    path = write_library(library, tmp_path / "lib.json")
    with pytest.raises(LibraryFileError, match="field 'template'.*register the face"):
        read_library(path, template="a48")
    with pytest.raises(LibraryFileError, match="field 'vertex_count'.*this face has 9 vertices"):
        read_library(path, n_vertices=9)
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(LibraryFileError, match="bad.json"):
        read_library(tmp_path / "bad.json")
    (tmp_path / "lib.npz").write_bytes(b"PK\x03\x04 broken")
    with pytest.raises(LibraryFileError, match="lib.npz"):
        read_library(path)


# ------------------------------------------------------------------ FAP fit and corrective
def test_fap_fit_recovers_known_values_and_the_corrective_restores_the_scan(default_rig):
    rig = default_rig
    rig.reset()
    deformer = rig.deformer
    known = {3: 200.0, 5: -150.0, 6: 80.0, 7: 80.0, 12: 60.0, 13: 60.0}
    values = np.zeros(68)
    for n, v in known.items():
        values[n - 1] = v
    fap_part = deformer.displacement(values)
    rest = rig.face.vertices
    centre = rest[np.argmax(rest[:, 2])]
    detail = 0.4 * np.exp(-np.sum((rest - centre) ** 2, axis=1) / 50.0)[:, None] * np.array([0.0, 0.0, 1.0])
    fit = fit_faps(deformer, rest + fap_part, faps=sorted(known), align=False)
    np.testing.assert_allclose(fit.values[[n - 1 for n in known]], list(known.values()), rtol=1e-6, atol=1e-6)
    assert fit.rms_fap_only_mm < 1e-6
    fit = fit_faps(deformer, rest + fap_part + detail, faps=sorted(known), align=False)
    assert fit.rms_with_corrective_mm < 1e-9 < fit.rms_fap_only_mm
    corrective = Corrective.from_fit("nose_detail", fit)
    layer = CorrectiveLayer(rig.faps, [corrective])
    try:
        rig.add_layer(layer)
        rig.set_faps({n: v for n, v in zip(fit.fitted, fit.values[[n - 1 for n in fit.fitted]])})
        assert layer.weights()[0] == pytest.approx(1.0)
        np.testing.assert_allclose(rig.vertices(), rest + fap_part + detail, atol=1e-6)
        twin = rig.copy()                                         # the copy's corrective follows the copy's FAPs
        twin.reset_faps()
        np.testing.assert_array_equal(twin.vertices(), rest)
        np.testing.assert_allclose(rig.vertices(), rest + fap_part + detail, atol=1e-6)
    finally:
        rig.remove_layer("correctives")
        rig.reset()


# ------------------------------------------------------------------ the built-in library
def test_builtin_library_on_the_default_face_through_a_project(default_rig, tmp_path):
    from core.formats.project import FaceRef, Project, load_project, save_project
    from core.layers.blend.builtin import builtin_library
    from core.rig import FaceRig

    lib = builtin_library()
    assert lib is not None and lib.template == "mpeg4_80" and lib.n_vertices == 4560
    assert {"joy", "surprise", "viseme_1", "viseme_14"} <= set(lib.names)
    rig = default_rig
    rig.reset()
    try:
        assert rig.ensure_layers(["blend:joy"]) == ["blend"]            # the registered factory finds it
        rig.set_values({"blend:joy": 80.0})
        moved = np.linalg.norm(np.array(rig.vertices()) - rig.face.vertices, axis=1)
        # Joy moves the cheeks and mouth corners by millimetres (80 % of the library's joy: 4.75 mm at
        # most since the surface guard smooths the raised cheek under the eye; the FAP preset's cheek
        # moves 9.2 mm at 100 %, 10.1 before)
        assert 4.0 < moved.max() < 40.0
        for part in ("eyeball_l", "eyeball_r", "teeth_upper"):
            assert moved[rig.face.parts[part]].max() == 0.0               # parts that stay with the skull
        path = tmp_path / "blend.mimica"
        save_project(path, Project.from_state(rig.face, FaceRef.default_face(), rig))
        assert '"blend:joy": 80.0' in path.read_text(encoding="utf-8")
        fresh = FaceRig(rig.face, rig.deformer)
        assert load_project(path).rig.apply(fresh) == {}
        assert fresh.value("blend:joy") == 80.0
        np.testing.assert_array_equal(fresh.vertices(), rig.vertices())
    finally:
        rig.remove_layer("blend")
        rig.reset()


def test_builtin_library_is_transferred_onto_another_rigged_face():
    from core.layers.blend.builtin import builtin_library, transferred_to
    from core.registration.correspondence import canonical_triangles

    lib = builtin_library()
    other = 1.1 * lib.rest + 3.0                                  # another (larger) person's canonical face
    moved = transferred_to(lib, other, "deformation")
    assert moved.transfer == "deformation" and moved.names == lib.names
    np.testing.assert_array_equal(moved.rest, other)
    bbox = transferred_to(lib, other, "bbox")
    np.testing.assert_allclose(bbox.displacements, 1.1 * lib.displacements, atol=1e-9)
    assert transferred_to(lib, lib.rest) is lib
    assert canonical_triangles("mpeg4_80").max() + 1 == lib.n_vertices


def test_a_persons_scans_become_a_library_with_a_summary(default_rig):
    """Virtual scans of the default face (neutral, joy) through landmarks → registration → library."""
    from core.layers.blend.scans import library_from_scans
    from core.registration.virtual_scanner import scan_face

    rig = default_rig
    rig.reset()
    neutral = scan_face(rig.face, noise_mm=0.05, rng=1).face
    rig.set_expression("joy", 1.0)
    joy = scan_face(rig.face, vertices=np.array(rig.vertices()), noise_mm=0.05, rng=2).face
    rig.reset()
    given = {"neutral": {n: neutral.landmarks[n] for n in neutral.landmark_names}}   # "corrected" by the user
    lib, reports = library_from_scans(neutral, {"joy": joy}, landmarks=given, base="default face")
    assert lib.names == ("joy",) and lib.n_vertices == 4560 and lib.template == "mpeg4_80"
    assert [r.pose for r in reports] == ["neutral", "joy"]
    assert reports[0].landmarks == "given" and reports[1].landmarks == "detected"
    assert "joy: landmarks detected" in reports[1].line()
    moved = np.linalg.norm(lib.displacements[0], axis=1)
    assert 5.0 < moved.max() < 40.0 and np.percentile(moved, 10) < 1.0, np.percentile(moved, [10, 50])   # mouth moves, forehead not
    assert lib.base == "default face; poses smoothed over 6 mm"      # the registration's wobble taken out
    with pytest.raises(LibraryError, match="pose names"):
        library_from_scans(neutral, {"Joy!": joy}, landmarks=given)
    with pytest.raises(LibraryError, match="smoothing width"):
        library_from_scans(neutral, {"joy": joy}, landmarks=given, smoothing_mm=-2)


def test_fap_unit_transfer_scales_each_region_by_its_own_unit():
    """Known answers: onto the base itself the identity, onto a uniformly scaled copy that scale; onto
    a face whose mouth alone is wider (mouth width +14 %, head's width +1 %) the mouth corner's
    sideways motion grows with the mouth's width, and skin no FAP region reaches follows the
    bounding box."""
    from core.layers.blend.builtin import builtin_library
    from core.layers.blend.transfer import canonical_fapu, fap_unit_scales, region_weights_of, transfer_fap_units
    from core.registration.templates import get_template

    lib = builtin_library()
    weights = region_weights_of(lib.rest, "mpeg4_80")
    np.testing.assert_allclose(transfer_fap_units(lib.rest, lib.displacements, lib.rest, weights),
                               lib.displacements, atol=1e-12)
    model, R = _rigid(1.1 * lib.rest, angle_deg=12.0)
    np.testing.assert_allclose(transfer_fap_units(lib.rest, lib.displacements, model, weights),
                               1.1 * lib.displacements @ R.T, atol=1e-9)
    base = get_template("mpeg4_80").base
    corner = base.index("8.3")
    mouth = 0.5 * (lib.rest[corner] + lib.rest[base.index("8.4")])
    near = np.exp(-np.sum((lib.rest - mouth) ** 2, axis=1) / (2 * 30.0 ** 2))   # a Gaussian about the mouth
    wide = lib.rest.copy()
    wide[:, 0] = mouth[0] + (lib.rest[:, 0] - mouth[0]) * (1 + 0.2 * near)
    ratio = canonical_fapu(wide, "mpeg4_80")["MW"] / canonical_fapu(lib.rest, "mpeg4_80")["MW"]
    S = fap_unit_scales(lib.rest, wide, weights)
    bbox = (wide.max(0) - wide.min(0)) / (lib.rest.max(0) - lib.rest.min(0))
    assert ratio > 1.12 and bbox[0] < 1.03
    assert S[corner, 0] > 1 + 0.7 * (ratio - 1) and abs(S[corner, 1] - 1.0) < 0.02     # wider, not taller
    reached = sum(np.abs(w) for w in weights.values())
    untouched = np.nonzero(reached == 0)[0]
    assert len(untouched) > 100
    np.testing.assert_allclose(S[untouched], np.tile(bbox, (len(untouched), 1)), atol=1e-5)   # (after alignment)
    with pytest.raises(LibraryError, match="region weights cover"):
        fap_unit_scales(lib.rest, wide, {3: np.ones(5)})
    moved = transfer_library(lib, wide, method="fap_units", region_weights=weights)
    assert moved.transfer == "fap_units"


def _canonical_default(rig):
    from core.face import Face
    from core.registration.correspondence import canonical_triangles, with_canonical_landmarks

    return with_canonical_landmarks(Face(np.array(rig.deformer.dense.vertices), canonical_triangles("mpeg4_80")))


def test_register_pose_on_the_neutral_itself_and_on_a_moved_copy(default_rig):
    """A pose registered from the neutral: the neutral as its own scan gives the neutral back; a
    rigidly moved copy gives the moved vertices (closest points of a vertex on its own mesh)."""
    from core.layers.blend.pose_registration import register_pose

    neutral = _canonical_default(default_rig)
    lms = {n: neutral.landmarks[n] for n in neutral.landmark_names}
    same = register_pose(neutral, lms, neutral)
    np.testing.assert_allclose(same.vertices, neutral.vertices, atol=1e-9)
    moved_v, _ = _rigid(neutral.vertices, angle_deg=6.0)
    moved = register_pose(neutral.with_vertices(moved_v), lms, neutral)
    np.testing.assert_allclose(moved.vertices, moved_v, atol=1e-6)
    with pytest.raises(LibraryError, match="at least 4"):
        register_pose(neutral, {n: lms[n] for n in list(lms)[:3]}, neutral)
