"""Which known-wrong gradients a run repairs, in which order, and at what cost (``repair:``).

A parameter is a candidate when its reverse-mode gradient is known to be wrong: its kind is
``biased`` in the trust table, or ``no_gradient`` there (thindielectric η); a self-check found it
``suspect``, or found components exactly 0 in a throughput weight (Mitsuba's replay ends the path
there); or it belongs to a composite BSDF over a smooth (delta) lobe that prb differentiates
through ``eval()``, which omits that lobe. Textures are never repaired: a difference per texel
would need two renders for each of thousands of texels.

The cost is counted in samples. The run's own passes cost about ``pixels × spp × (1 + 2 P)``
(a primal, and P backward passes of about two primals each) plus their fixed costs
(RENDER_OVERHEAD, BACKWARD_OVERHEAD); ``repair.budget`` times that is
what the differences may render. Each repaired component costs two renders per seed (a base
render per seed is shared by the one-sided ones), each its samples plus RENDER_OVERHEAD; the
renders' spp is what fits, at most the job's. When not even one sample per pixel fits, the
parameters that matter least (the reverse mode's |θ·∂M/∂θ|, then |∂M/∂θ|) are left out,
labelled as before and named.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from sensaov_cli.buffer.model import ParamRecord
from sensaov_cli.job.spec import RepairSpec
from sensaov_cli.render.loading import LoadedScene
from sensaov_cli.render.verify.selfcheck import THROUGHPUT_TYPES
from sensaov_cli.render.verify.trust import (
    COMPOSITE_REASON,
    TABLE,
    ZERO_VALUE_REASON,
    repair_entry,
)

# A parameter with more components is not repaired by differences (two renders each).
MAX_COMPONENTS = 16
# What a render costs besides its samples, in samples: setting the parameter (Mitsuba
# recomputes a roughplastic's tables: 14 ms) and tracing the integrator (9 ms) come to about
# as much as 2^15 samples at the 1.8 M samples/s of 2 CPU cores (measured on the interior,
# 128x128: 38 ms for 3 spp, 19 ms for 1). A backward pass costs about 2^19 besides its
# samples (200-400 ms on cbox from 24x24 to 128x128, against 30-50 ms for a primal).
RENDER_OVERHEAD = 1 << 15
BACKWARD_OVERHEAD = 1 << 19
TEXTURE_REASON = "a texture: finite differences would take two renders per texel"
# Where a difference must not step past a bound: a throughput weight below 0 ends Mitsuba's
# replayed path, a blend weight is clamped to [0, 1]. Components within a step of one are
# differenced one-sided, away from it.
BOUNDS: dict[str, tuple[float | None, float | None]] = {
    **{kind: (0.0, None) for kind in THROUGHPUT_TYPES},
    "weight": (0.0, 1.0),
}


@dataclass(frozen=True)
class Target:
    """One parameter to repair: why, how many components, which go one-sided, its step."""

    key: str
    reason: str
    components: int
    one_sided: tuple[tuple[int, int], ...]  # (component, ±1): one-sided, away from a bound
    step: float
    priority: tuple[float, float]  # reverse mode's max |θ·∂M/∂θ| and |∂M/∂θ| over objectives


@dataclass(frozen=True)
class RepairPlan:
    targets: tuple[Target, ...]  # repaired, most important first
    skipped: dict[str, str]  # key -> why it was not repaired
    spp: int  # of every difference render (0: nothing to render)
    seeds: tuple[int, ...]
    budget_samples: int  # what repair.budget allows
    samples: int  # what the plan renders

    def renders_per_seed(self) -> int:
        return renders_per_seed(self.targets)


def candidates(
    loaded: LoadedScene, records: Sequence[ParamRecord], zero_components: Mapping[str, int]
) -> dict[str, str]:
    """key -> why its reverse-mode gradient is known wrong, for every selected parameter."""
    found = {}
    for record in records:
        table = TABLE.get((record.plugin, record.type))
        if record.trust in ("biased", "suspect"):
            found[record.key] = f"{record.trust}: {record.note}"
        elif record.trust == "no_gradient" and (
            record.note == ZERO_VALUE_REASON or (table and table.trust == "no_gradient")
        ):
            found[record.key] = f"no gradient: {record.note}"
        elif record.key in zero_components:
            found[record.key] = record.note or "value exactly 0 in some components"
        elif _over_smooth_lobe(loaded, record):
            found[record.key] = COMPOSITE_REASON
    return found


def planned(loaded: LoadedScene) -> dict[str, str]:
    """Before any render (``sensaov params``): key -> why a run would repair it, budget
    permitting; zero components are read from the values, as the self-checks will."""
    zeros = {}
    for record in loaded.selected:
        value = np.asarray(loaded.params[record.key])
        if record.type in THROUGHPUT_TYPES and not record.is_texture and np.any(value == 0):
            zeros[record.key] = int(np.count_nonzero(value == 0))
    return candidates(loaded, loaded.selected, zeros)


def _over_smooth_lobe(loaded: LoadedScene, record: ParamRecord) -> bool:
    """Whether prb differentiates ``record`` through a BSDF that has a delta lobe."""
    if loaded.routes.get(record.key) != "prb":  # composites prb gets wrong go through path
        return False
    mi, hierarchy = loaded.mi, loaded.params.hierarchy
    node = loaded.params.properties[record.key][2]
    while node is not None and not isinstance(node, mi.BSDF):
        node = hierarchy.get(node, (None,))[0]
    return node is not None and bool(mi.has_flag(node.flags(), mi.BSDFFlags.Delta))


def renders_per_seed(targets: Sequence[Target]) -> int:
    """Two renders per component, and one base render shared by the one-sided ones."""
    return sum(2 * t.components for t in targets) + any(t.one_sided for t in targets)


def run_samples(pixels: int, spp: int, passes: int) -> int:
    """What the run's own passes cost, in samples: a primal and P backward passes of ~2."""
    return pixels * spp * (1 + 2 * passes) + RENDER_OVERHEAD + BACKWARD_OVERHEAD * passes


def plan(
    reasons: Mapping[str, str],
    records: Sequence[ParamRecord],
    values: Mapping[str, np.ndarray],
    grads: Mapping[str, Mapping[str, np.ndarray]],
    settings: RepairSpec,
    *,
    pixels: int,
    spp: int,
    passes: int,
    seeds: Sequence[int],
) -> RepairPlan:
    """The targets that fit ``settings.budget``, and why the others were left out."""
    budget = int(settings.budget * run_samples(pixels, spp, passes))
    by_key = {r.key: r for r in records}
    skipped, targets = {}, []
    for key, reason in reasons.items():
        record = by_key[key]
        size = int(np.prod(record.shape))
        if record.is_texture or size > MAX_COMPONENTS:
            skipped[key] = TEXTURE_REASON if record.is_texture else f"{size} components"
            continue
        targets.append(_target(record, reason, values[key], grads, settings))
    targets.sort(key=lambda t: t.priority, reverse=True)
    fd_spp = 0
    while targets:
        renders = len(seeds) * renders_per_seed(targets)
        fd_spp = min(spp, (budget // renders - RENDER_OVERHEAD) // pixels)
        if fd_spp >= 1:
            break
        dropped = targets.pop()
        skipped[dropped.key] = f"over the repair budget (repair.budget {settings.budget:g})"
    samples = (fd_spp * pixels + RENDER_OVERHEAD) * len(seeds) * renders_per_seed(targets)
    return RepairPlan(tuple(targets), skipped, fd_spp, tuple(seeds), budget, samples)


def _target(
    record: ParamRecord,
    reason: str,
    value: np.ndarray,
    grads: Mapping[str, Mapping[str, np.ndarray]],
    settings: RepairSpec,
) -> Target:
    step = settings.step or repair_entry(record.plugin, record.type).step
    flat = value.astype(np.float64).ravel()
    low, high = BOUNDS.get(record.type, (None, None))
    eps = step * np.maximum(1.0, np.abs(flat))
    one_sided = tuple(
        (int(i), 1 if low is not None and flat[i] - eps[i] < low else -1)
        for i in range(flat.size)
        if (low is not None and flat[i] - eps[i] < low)
        or (high is not None and flat[i] + eps[i] > high)
    )
    weighted = max(
        (float(np.abs(flat * g[record.key].ravel()).sum()) for g in grads.values()), default=0.0
    )
    raw = max((float(np.abs(g[record.key]).sum()) for g in grads.values()), default=0.0)
    return Target(record.key, reason, flat.size, one_sided, step, (weighted, raw))
