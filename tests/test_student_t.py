"""Student's t, the rule behind a ranking's `resolved` column (buffer/statistics.py)."""

from __future__ import annotations

import math

import pytest

from sensaov_cli.buffer.statistics import interval_factor, t_cdf, t_quantile

# Two-sided 95 % points of Student's t (any statistics table).
TABLE = {1: 12.7062, 2: 4.3027, 3: 3.1824, 4: 2.7764, 9: 2.2622, 30: 2.0423}


@pytest.mark.parametrize(("dof", "point"), TABLE.items())
def test_the_95_percent_points(dof: int, point: float) -> None:
    assert interval_factor(dof + 1) == pytest.approx(point, abs=5e-5)
    assert t_quantile(0.025, dof) == pytest.approx(-point, abs=5e-5)


def test_the_cdf_against_closed_forms() -> None:
    for x in (-3.0, -0.5, 0.0, 0.7, 2.0, 10.0):
        assert t_cdf(x, 1) == pytest.approx(0.5 + math.atan(x) / math.pi, abs=1e-12)  # Cauchy
        assert t_cdf(x, 2) == pytest.approx(0.5 + x / (2 * math.sqrt(2 + x * x)), abs=1e-12)
    assert t_cdf(1.96, 1e6) == pytest.approx(0.975, abs=1e-5)  # the normal limit


def test_two_standard_errors_cover_86_percent_at_four_batches() -> None:
    """Why 2 SE was overconfident: with 3 dof it covers 86 %, not 95 %."""
    assert 2 * t_cdf(2.0, 3) - 1 == pytest.approx(0.8607, abs=1e-4)


def test_refuses_what_has_no_meaning() -> None:
    for call in (lambda: interval_factor(1), lambda: t_quantile(1.0, 3), lambda: t_cdf(0.0, 0)):
        with pytest.raises(ValueError):
            call()
