"""``statistics.heavy_tail``: heavy-tailed batch estimates are found, light-tailed ones rarely."""

from __future__ import annotations

import numpy as np
import pytest

from sensaov_cli.buffer.statistics import TAIL_FALSE_ALARM, heavy_tail, tail_threshold

DRAWS = 3000  # sets of batch estimates per distribution


def _rate(sets: np.ndarray) -> float:
    return float(np.mean([heavy_tail(row) is not None for row in sets]))


@pytest.mark.parametrize("batches", [4, 6, 8, 16, 32])
def test_normal_estimates_fire_at_the_stated_rate(batches: int) -> None:
    """The threshold is found by a simulation at a seed of its own: at other seeds, normal
    batch estimates fire about TAIL_FALSE_ALARM of the time (binomial error at 3000 draws)."""
    rng = np.random.default_rng(1000 + batches)
    rate = _rate(rng.normal(5.0, 3.0, (DRAWS, batches)))
    assert rate <= TAIL_FALSE_ALARM + 4 * np.sqrt(TAIL_FALSE_ALARM / DRAWS)


def test_skewed_light_tailed_estimates_rarely_fire() -> None:
    """Means of a few exponential samples (a dim, skewed pixel) are not a heavy tail."""
    rng = np.random.default_rng(7)
    assert _rate(rng.exponential(1.0, (DRAWS, 8, 4)).mean(axis=2)) < 0.04
    assert _rate(rng.lognormal(0.0, 1.0, (DRAWS, 8, 16)).mean(axis=2)) < 0.05


def test_fireflies_are_found() -> None:
    """A rare large path in some batches (a near-specular lobe's derivative): found in most of
    the runs that have one, with 8 batches, and more often with more batches."""
    rng = np.random.default_rng(8)

    def fireflies(batches: int) -> np.ndarray:
        spikes = (rng.random((DRAWS, batches)) < 0.25) * rng.exponential(30.0, (DRAWS, batches))
        return rng.standard_normal((DRAWS, batches)) + spikes * rng.choice([-1, 1], spikes.shape)

    assert _rate(fireflies(8)) > 0.6
    assert _rate(fireflies(32)) > 0.95


def test_the_issue_case_is_found() -> None:
    """Per-seed values of a rough dielectric's η with roughness texels at 0 (Mitsuba alone:
    −100 to +12 where central differences give +0.03): one huge batch among small ones."""
    reason = heavy_tail([0.8, -1.2, 0.3, 11.9, -0.6, 0.2, -99.7, 1.1])
    assert reason is not None and "2 of 8" in reason


def test_what_it_does_not_judge() -> None:
    assert heavy_tail([1.0, 50.0, 2.0]) is None  # too few batches to tell
    assert heavy_tail([2.0] * 8) is None  # no spread at all
    assert heavy_tail([1.0, 2.0, float("nan"), 1.5]) is None  # not a number: not its call
    # all but one batch equal: a parameter that a rare path reached once
    assert "which are all equal" in (heavy_tail([0.0] * 7 + [3.0]) or "")


def test_unequal_batches_are_weighed_by_their_samples() -> None:
    """A shard of 64x the samples of the others should lie 8x (sqrt of spp) closer to the
    truth: a deviation ordinary for a small shard is an outlier for it."""
    values = [1.0, 1.1, 0.9, 1.05, 0.95, 1.02, 0.98, 1.3]
    assert heavy_tail(values) is None
    assert heavy_tail(values, spp=[1] * 7 + [64]) is not None


def test_threshold_is_reproducible_and_falls_with_batches() -> None:
    assert tail_threshold(8) == tail_threshold.__wrapped__(8)
    assert tail_threshold(8) > tail_threshold(16) > tail_threshold(64)
