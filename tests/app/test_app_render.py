"""app.render: off-screen PNG rendering with the shared scene code."""

from __future__ import annotations

import numpy as np
import pytest
from app_helpers import image_difference, image_variance
from PIL import Image

from app.render import render_face_image, render_face_png


def test_render_face_png_writes_non_blank_image(tmp_path, synthetic_face):
    out = render_face_png(synthetic_face, tmp_path / "face.png", size=(320, 240))
    img = np.asarray(Image.open(out))
    assert img.shape[:2] == (240, 320)
    assert image_variance(img) > 100


def test_render_modes_and_views_differ(synthetic_face):
    kw = dict(size=(240, 180))
    textured = render_face_image(synthetic_face, mode="textured", **kw)
    wire = render_face_image(synthetic_face, mode="wireframe", **kw)
    side = render_face_image(synthetic_face, view="side", **kw)
    marked = render_face_image(synthetic_face, show_landmarks=True, **kw)
    assert image_difference(textured, wire) > 3
    assert image_difference(textured, side) > 3
    changed = (np.abs(textured.astype(int) - marked.astype(int)).sum(axis=2) > 40).sum()
    assert changed > 6 * 20


def test_render_jpg(tmp_path, synthetic_face):
    out = render_face_png(synthetic_face, tmp_path / "face.jpg", size=(200, 150), mode="points")
    assert Image.open(out).format == "JPEG"


def test_render_rejects_bad_arguments(synthetic_face, tmp_path):
    with pytest.raises(ValueError, match="view"):
        render_face_png(synthetic_face, tmp_path / "x.png", view="top")
    with pytest.raises(ValueError, match="display mode"):
        render_face_png(synthetic_face, tmp_path / "x.png", mode="toon", size=(64, 64))
    with pytest.raises(ValueError, match="too small"):
        render_face_png(synthetic_face, tmp_path / "x.png", size=(4, 4))


def test_frame_points_choose_what_the_camera_frames(synthetic_face):
    whole = render_face_image(synthetic_face, size=(160, 120))
    same = render_face_image(synthetic_face, size=(160, 120), frame_points=synthetic_face.vertices)
    corner = synthetic_face.vertices[synthetic_face.vertices[:, 0] > np.percentile(synthetic_face.vertices[:, 0], 80)]
    framed = render_face_image(synthetic_face, size=(160, 120), frame_points=corner)
    assert np.array_equal(whole, same)
    assert image_difference(whole, framed) > 3
