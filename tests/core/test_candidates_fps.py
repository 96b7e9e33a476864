"""Farthest-point sampling (untextured scans' landmark candidates): a known answer."""

import numpy as np

from core.registration.candidates import farthest_point_sampling


def test_farthest_point_sampling_matches_a_brute_force_reference():
    pts = np.random.default_rng(3).normal(size=(400, 3)) * [30.0, 20.0, 10.0]
    got = farthest_point_sampling(pts, 40)
    start = int(np.argmin(np.linalg.norm(pts - pts.mean(axis=0), axis=1)))
    want = [start]
    for _ in range(39):
        d = np.min(np.linalg.norm(pts[:, None] - pts[want][None], axis=2), axis=1)
        want.append(int(np.argmax(d)))
    assert got.tolist() == want
