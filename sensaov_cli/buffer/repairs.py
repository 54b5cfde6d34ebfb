"""Gradients repaired by finite differences: how each was computed, and its own spread.

Where Mitsuba's reverse-mode gradient of a parameter is known to be wrong (docs/verification.md,
"Repairs"), ``sensaov run`` stores central differences with common random numbers in its place:
per seed s and component c, (M(θ + ε e_c; s) − M(θ − ε e_c; s)) / 2ε, both sides rendered with
the same samples; a component within a step of a bound (a throughput weight at 0, a blend
weight at 0 or 1) takes the one-sided (−3 M(θ; s) + 4 M(θ + h e_c; s) − M(θ + 2h e_c; s)) / 2h,
h = ±ε away from the bound, as accurate.
A :class:`Repair` keeps every seed's estimate, so the stored gradient's standard error and its
sign's significance come from its own spread, and the reverse-mode gradient it replaced (duality
with forward mode holds for that one). numpy only; the header's JSON form is buffer/npz.py's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from sensaov_cli.errors import BufferContentError

# Two-sided 95 % points of Student's t by degrees of freedom (seeds − 1): a sign is significant
# when |Σc| exceeds this many standard errors of a repair's own few seeds (3.18 at 4 seeds).
_T_975 = {1: 12.71, 2: 4.30, 3: 3.18, 4: 2.78, 5: 2.57, 6: 2.45, 7: 2.36, 8: 2.31, 9: 2.26,
          10: 2.23, 15: 2.13, 20: 2.09, 30: 2.04}  # fmt: skip


def t_975(seeds: int) -> float:
    """The significance threshold for a mean of ``seeds`` estimates (next tabulated dof below)."""
    dof = max(seeds - 1, 1)
    return _T_975[max(d for d in _T_975 if d <= dof)] if dof <= 30 else 1.96


@dataclass(frozen=True)
class Repair:
    """How one parameter's stored gradient was computed by finite differences."""

    reason: str  # why the reverse-mode gradient was not kept: its label and note
    step: float  # relative step: ε = step · max(1, |θ_c|) per component
    spp: tuple[int, ...]  # samples per pixel of each seed's renders
    seeds: tuple[int, ...]  # one per estimate
    # (flat index, +1 or -1) of components differenced one-sided, away from a bound
    one_sided: tuple[tuple[int, int], ...]
    estimates: Mapping[str, np.ndarray]  # objective -> (seeds, components) float64
    reverse: Mapping[str, np.ndarray]  # objective -> (components,) the gradient it replaced
    seconds: float  # wall time of its renders

    def __post_init__(self) -> None:
        count = len(self.seeds)
        _require(count >= 1 and len(self.spp) == count, "a repair needs seeds, spp for each")
        _require(self.step > 0 and math.isfinite(self.step), f"repair step {self.step!r}")
        _require(min(self.spp) >= 1, f"repair spp {self.spp!r}")
        sizes = {np.shape(e)[1:] for e in self.estimates.values()}
        sizes |= {np.shape(r) for r in self.reverse.values()}
        _require(len(sizes) == 1 and len(next(iter(sizes))) == 1, "repair arrays differ in size")
        _require(sorted(self.estimates) == sorted(self.reverse), "repair objectives differ")
        for name, estimates in self.estimates.items():
            _require(np.shape(estimates)[0] == count, f"repair of {name!r}: one row per seed")
            _require(bool(np.isfinite(estimates).all()), f"repair of {name!r}: not finite")
        _require(
            all(0 <= i < self.components and sign in (1, -1) for i, sign in self.one_sided),
            f"one_sided {self.one_sided!r}: (index, +1 or -1) pairs within the parameter",
        )

    @property
    def components(self) -> int:
        return int(np.shape(next(iter(self.reverse.values())))[0]) if self.reverse else 0

    def mean(self, objective: str) -> np.ndarray:
        return np.asarray(self.estimates[objective]).mean(axis=0)

    @property
    def has_error(self) -> bool:
        """Whether its own seeds give a standard error (a shard's share may be one seed: its
        merge has them all, and batch statistics beside)."""
        return len(self.seeds) >= 2

    def stderr(self, objective: str) -> np.ndarray:
        """Per component, the standard error of the mean over seeds (needs has_error)."""
        rows = np.asarray(self.estimates[objective])
        return rows.std(axis=0, ddof=1) / math.sqrt(len(rows))

    def signed_error(self, objective: str, weights: np.ndarray) -> float:
        """Standard error of Σ_c w_c g_c (w = θ for value-weighted sums, ones for raw)."""
        sums = np.asarray(self.estimates[objective]) @ weights.astype(np.float64).ravel()
        return float(sums.std(ddof=1) / math.sqrt(len(sums)))

    def norm_error(self, objective: str, weights: np.ndarray) -> float:
        """Standard error of ‖w · g‖ to first order: each seed's projection on the mean (the
        linearisation the batch statistics use, buffer/statistics.py)."""
        rows = np.asarray(self.estimates[objective]) * weights.astype(np.float64).ravel()
        mean = rows.mean(axis=0)
        norm = float(np.linalg.norm(mean))
        if norm == 0:
            return 0.0
        projections = rows @ mean / norm
        return float(projections.std(ddof=1) / math.sqrt(len(projections)))

    def significant(self, signed: float, error: float) -> bool:
        """Whether |signed| is beyond noise: Student's t at 95 % with seeds − 1 dof."""
        return abs(signed) > t_975(len(self.seeds)) * error


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise BufferContentError(message)
