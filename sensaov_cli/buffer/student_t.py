"""Student's t distribution: the quantile that turns a standard error from k batches into an
interval (standard library only).

A mean over k batches has a standard error estimated from those same k batches, so
(mean − truth) / SE follows Student's t with k − 1 degrees of freedom, not a normal law: with
4 batches a ±2 SE interval covers about 86 %, not 95 %; the 95 % interval is ±3.18 SE.
"""

from __future__ import annotations

import math

SIGNIFICANCE_LEVEL = 0.95  # two-sided: a sign is significant when outside the 95 % interval


def t_cdf(x: float, dof: float) -> float:
    """P(T ≤ x) for Student's t with ``dof`` > 0 degrees of freedom."""
    if not dof > 0:
        raise ValueError(f"degrees of freedom must be positive, got {dof}")
    if x == 0.0:
        return 0.5
    tail = 0.5 * _incomplete_beta(dof / (dof + x * x), dof / 2.0, 0.5)
    return 1.0 - tail if x > 0 else tail


def t_quantile(probability: float, dof: float) -> float:
    """The x with P(T ≤ x) = ``probability`` (bisection on :func:`t_cdf`, to 1e-12)."""
    if not 0.0 < probability < 1.0:
        raise ValueError(f"probability must lie in (0, 1), got {probability}")
    if probability < 0.5:
        return -t_quantile(1.0 - probability, dof)
    low, high = 0.0, 1.0
    while t_cdf(high, dof) < probability:
        high *= 2.0
    while high - low > 1e-12 * max(1.0, high):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if t_cdf(middle, dof) < probability else (low, middle)
    return 0.5 * (low + high)


def interval_factor(batches: int, level: float = SIGNIFICANCE_LEVEL) -> float:
    """How many standard errors from ``batches`` batches make a two-sided ``level`` interval."""
    if batches < 2:
        raise ValueError(f"a standard error needs at least 2 batches, got {batches}")
    return t_quantile(0.5 + level / 2.0, batches - 1)


def _incomplete_beta(x: float, a: float, b: float) -> float:
    """The regularised incomplete beta function I_x(a, b), by its continued fraction."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = (
        math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    )
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _fraction(x, a, b) / a
    return 1.0 - math.exp(log_front) * _fraction(1.0 - x, b, a) / b


def _fraction(x: float, a: float, b: float) -> float:
    """The continued fraction of I_x(a, b) (modified Lentz), converging for x < (a+1)/(a+b+2)."""
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    result = d
    for m in range(1, 300):
        for numerator in (
            m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
            -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1)),
        ):
            d = 1.0 + numerator * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + numerator / c
            c = c if abs(c) > tiny else tiny
            result *= c * d
        if abs(c * d - 1.0) < 1e-15:
            break
    return result
