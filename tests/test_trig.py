"""The vectorisable sincos and atan2 agree with the C library to an ulp or two."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mmg.trig import atan2, cos, sin, sincos


def test_sincos_within_an_ulp_over_a_wide_range():
    rng = np.random.default_rng(0)
    xs = np.concatenate([rng.uniform(-10, 10, 5000), rng.uniform(-1e5, 1e5, 5000)])
    for x in xs:
        s, c = sincos(float(x))
        assert abs(s - math.sin(x)) <= 2.3e-16
        assert abs(c - math.cos(x)) <= 2.3e-16


def test_sincos_special_values():
    assert sincos(0.0) == (0.0, 1.0)
    s, c = sincos(math.pi / 2)
    assert s == 1.0 and abs(c) < 1e-16
    assert all(math.isnan(v) for v in sincos(math.inf))
    assert all(math.isnan(v) for v in sincos(math.nan))
    assert all(math.isnan(v) for v in sincos(-1e300))
    assert all(abs(v) <= 1.0 for v in sincos(1e12))


def test_atan2_within_two_ulps_and_quadrants():
    rng = np.random.default_rng(1)
    ys = rng.normal(size=5000) * 10 ** rng.uniform(-5, 3, 5000)
    xs = rng.normal(size=5000) * 10 ** rng.uniform(-5, 3, 5000)
    for y, x in zip(ys, xs, strict=True):
        ref = math.atan2(y, x)
        assert atan2(float(y), float(x)) == pytest.approx(ref, rel=4.5e-16, abs=1e-300)
    for y, x in [(0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (0.0, -1.0), (-0.0, -1.0), (1.0, -1.0)]:
        assert atan2(y, x) == math.atan2(y, x)


def test_sin_and_cos_are_the_halves_of_sincos():
    for x in (0.3, -2.0, 7.5, 1e4):
        assert (sin(x), cos(x)) == sincos(x)
