"""A closed eye's lid line follows the skin's own crease (core.registration.lid_crease), and the cut
margin moves smoothly along it (core.registration.scan_mouth)."""

import numpy as np
import pytest

from core.layers.fap.closed_eyes import LidLine
from core.registration.correspondence import SurfaceRays

WIDTH = 30.0


def _line() -> LidLine:
    """A closed eye lying in the xy plane (u = x, v = y, w = z), corners at x = 0 and 30 mm, its lid
    centres' middle 1 mm above the corners' chord."""
    return LidLine("l", np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]),
                   np.array([0.0, 0.0, 1.0]), WIDTH, WIDTH / 2, 1.0)


def _crease_offset(s):
    """The known crease: 3 mm below the parabola at the outer corner, 1.5 mm above at the inner one."""
    return -3.0 + 0.15 * np.asarray(s)


def _lid_surface(groove_mm: float, span=(-5.0, 35.0)):
    """A gently bulging lid (0.5 mm grid) with a groove ``groove_mm`` deep along the known crease,
    between ``span`` mm along the eye."""
    line = _line()
    s, t = np.meshgrid(np.arange(-5.0, 35.01, 0.5), np.arange(-12.0, 12.01, 0.5), indexing="ij")
    crease = line.parabola(s) + _crease_offset(s)
    groove = np.where((s >= span[0]) & (s <= span[1]), groove_mm, 0.0)
    z = 5.0 - 0.01 * (s - 15.0) ** 2 - 0.02 * t ** 2 - groove * np.exp(-0.5 * ((t - crease) / 0.7) ** 2)
    vertices = np.column_stack([s.ravel(), t.ravel(), z.ravel()])
    rows, cols = s.shape
    ids = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = ids[:-1, :-1].ravel(), ids[1:, :-1].ravel(), ids[1:, 1:].ravel(), ids[:-1, 1:].ravel()
    triangles = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    if SurfaceRays(vertices, triangles).engine != "embree":
        pytest.skip("the crease search casts rays (embreex)")
    return line, vertices, triangles


def test_the_lid_line_follows_a_crease_off_its_parabola():
    from core.registration.lid_crease import along_crease

    line, vertices, triangles = _lid_surface(groove_mm=1.5)
    found = along_crease(line, vertices, triangles)
    s = np.linspace(3.0, WIDTH - 3.0, 25)
    course = np.interp(s, found.crease_s, found.crease_t)
    assert np.abs(course - _crease_offset(s)).max() < 0.35          # mm, on a 0.25 mm raster
    # Heights are now measured from the crease: half a millimetre either side of it is upper / lower lid.
    on = np.column_stack([s, line.parabola(s) + _crease_offset(s), np.zeros_like(s)])
    above, inside = found.height(on + [0.0, 0.5, 0.0])
    below, _ = found.height(on - [0.0, 0.5, 0.0])
    assert inside.all() and (above > 0).all() and (below < 0).all()
    # ... and the parabola alone would put the upper lid's lowest 2.5 mm on the lower side near the corner.
    assert line.height(on[:1] + [0.0, 0.5, 0.0])[0][0] < 0


def test_a_lid_without_a_crease_keeps_its_parabola():
    """Lids that meet smoothly (no groove), or a fold along a fifth of the eye only (a lower lid's
    fold, scanner noise), keep the landmarks' parabola."""
    from core.registration.lid_crease import along_crease

    for groove_mm, span in ((0.0, (-5.0, 35.0)), (1.5, (12.0, 18.0))):
        line, vertices, triangles = _lid_surface(groove_mm, span)
        assert along_crease(line, vertices, triangles) == line


def test_the_cut_margin_moves_as_its_neighbours_along_the_lid_line():
    """Each crossing point of the cut is averaged with its eye's others along u (rows sum to 1), not
    with the other eye's."""
    from core.registration.scan_mouth import MARGIN_SMOOTH_MM, _along_margin

    line = _line()
    other = LidLine("r", np.array([-70.0, 0.0, 0.0]), line.u, line.v, line.w, WIDTH, WIDTH / 2, 1.0)
    s = np.arange(1.0, 29.0, 0.8)
    points = np.column_stack([s, line.parabola(s), np.zeros_like(s)])
    points = np.concatenate([points, points - [70.0, 0.0, 0.0]])
    smooth = _along_margin(points, [line, other]).toarray()
    np.testing.assert_allclose(smooth.sum(axis=1), 1.0)
    half = len(s)
    assert not smooth[:half, half:].any() and not smooth[half:, :half].any()
    # A saw-tooth of 1 mm along the margin is flattened; a straight ramp stays a ramp inside the eye.
    tooth = np.where(np.arange(half) % 2, 1.0, 0.0)
    flattened = smooth[:half, :half] @ tooth
    assert np.ptp(flattened[5:-5]) < 0.2
    ramp = smooth[:half, :half] @ s
    np.testing.assert_allclose(ramp[5:-5], s[5:-5], atol=0.05 * MARGIN_SMOOTH_MM)
