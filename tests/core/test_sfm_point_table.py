"""The SFM landmark benchmark's per-point table (benchmarks/evaluate_landmarks_sfm.point_table):
mean signed offsets, spread and accuracy per ibug point and texture variant, from made-up results."""

import numpy as np


def _result(textured: bool, offsets, tolerance=5.0):
    from benchmarks.evaluate_landmarks_sfm import Result

    offsets = np.asarray(offsets, float)
    return Result("mpeg4_80", 0, "neutral", textured, 0.0, ("9.3", "3.7"), np.linalg.norm(offsets, axis=1),
                  offsets, np.ones(2), tolerance, 1.0, 1.0, 1000)


def test_point_table_gives_mean_offset_spread_and_accuracy_per_variant():
    from benchmarks.evaluate_landmarks_sfm import point_table

    rs = [_result(True, [[1, 0, 0], [0, 0, 0]]), _result(True, [[3, 0, 0], [0, 0, 0]]),
          _result(False, [[0, -6, 0], [np.nan] * 3]), _result(False, [[0, -2, 0], [np.nan] * 3])]
    lines = point_table(rs)
    rows = {tuple(line.split()[:4]): line.split() for line in lines[1:]}
    tex = rows[("9.3", "31", "|", "tex")]       # nose tip = ibug 31
    assert tex[4:10] == ["1.000", "2.00", "+2.0", "+0.0", "+0.0", "1.0"] and tex[-1] == "2"
    geo = rows[("9.3", "31", "|", "geo")]
    assert geo[4:10] == ["0.500", "4.00", "+0.0", "-4.0", "+0.0", "0.0"] and geo[10] == "2.0"
    assert ("3.7", "46", "|", "geo") not in rows   # never scored without texture: no row
    assert rows[("3.7", "46", "|", "tex")][4] == "1.000"
