"""Repairs: where Mitsuba's reverse-mode gradient is known wrong, central differences instead.

Per seed s and component c, (M(θ + ε e_c; s) − M(θ − ε e_c; s)) / 2ε with common random
numbers; a component within a step of a bound (BOUNDS) takes the one-sided (−3 M(θ) + 4 M(θ + h)
− M(θ + 2h)) / 2h, h = ±ε away from it; ε = step · max(1, |θ_c|) with the step measured per kind
(trust.REPAIRS). The mean over seeds replaces the stored gradient, their spread is its standard
error; with batches the seeds are dealt to them. The repaired label is the repair's own.
Textures are never repaired (two renders per texel). The renders' spp is what fits in
``repair.budget`` times the run's own cost; below 1 spp, the parameters that matter least
(|θ·∂M/∂θ|, then |∂M/∂θ|) are left out and named. docs/verification.md "Repairs" has the rules.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from sensaov_cli import interrupts
from sensaov_cli.buffer.model import ParamRecord, Repair
from sensaov_cli.buffer.statistics import with_batch_estimates
from sensaov_cli.job.spec import RepairSpec
from sensaov_cli.progress import Progress
from sensaov_cli.render.adjoint import AdjointResult, derived_seed, integrator_plan, render_primal
from sensaov_cli.render.loading import LoadedScene, assign
from sensaov_cli.render.objectives import Objective, value_and_adjoint
from sensaov_cli.render.verify.selfcheck import DENSITY_TYPES, THROUGHPUT_TYPES, zero_effect
from sensaov_cli.render.verify.tails import near_specular
from sensaov_cli.render.verify.trust import (
    COMPOSITE_REASON,
    TABLE,
    ZERO_VALUE_REASON,
    repair_entry,
)

MAX_COMPONENTS = 16  # more are not repaired (two renders each)
MAX_SEEDS = 1024  # a repair's seeds in all, the rounds added to resolve its sign included
# What a render costs besides its samples, in samples: setting the parameter (a roughplastic's
# tables) and tracing the integrator; a backward pass's (measured, bench/).
RENDER_OVERHEAD = 1 << 15
BACKWARD_OVERHEAD = 1 << 19
TEXTURE_REASON = "a texture: finite differences would take two renders per texel"
# A throughput weight below 0 ends Mitsuba's replayed path, a blend weight is clamped to [0, 1].
BOUNDS: dict[str, tuple[float | None, float | None]] = {
    **{kind: (0.0, None) for kind in THROUGHPUT_TYPES | DENSITY_TYPES},
    "weight": (0.0, 1.0),
    "roughness": (0.0, None),  # a near-specular lobe's roughness at 0 (render/verify/tails.py)
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


def candidates(
    loaded: LoadedScene, records: Sequence[ParamRecord], zero_components: Mapping[str, int]
) -> dict[str, str]:
    """key -> why its reverse-mode gradient is known wrong, or heavy-tailed where a repair is
    the better estimator (render/verify/tails.py), for every selected parameter."""
    heavy = near_specular(loaded)
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
        elif record.key in heavy:
            found[record.key] = heavy[record.key]
    return found


def planned(loaded: LoadedScene) -> dict[str, str]:
    """Before any render (``sensaov params``): key -> why a run would repair it, budget
    permitting; zero components are read from the values, as the self-checks will."""
    zeros = {}
    for record in loaded.selected:
        value = np.asarray(loaded.params[record.key])
        if zero_effect(record.plugin, record.type) and not record.is_texture and np.any(value == 0):
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
    batches: int = 1,
) -> RepairPlan:
    """The targets that fit ``settings.budget``, and why the others were left out."""
    # the run's own cost in samples: a primal and ``passes`` backward passes of ~2 renders each,
    # each pass's fixed cost once per batch
    fixed = RENDER_OVERHEAD + BACKWARD_OVERHEAD * passes
    run = pixels * spp * (1 + 2 * passes) + fixed * batches
    budget = int(settings.budget * run)
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
    near_low = flat - eps < low if low is not None else np.zeros(flat.size, bool)
    near_high = flat + eps > high if high is not None else np.zeros(flat.size, bool)
    near = np.flatnonzero(near_low | near_high)
    one_sided = tuple((int(i), 1 if near_low[i] else -1) for i in near)
    weighted = max(
        (float(np.abs(flat * g[record.key].ravel()).sum()) for g in grads.values()), default=0.0
    )
    raw = max((float(np.abs(g[record.key]).sum()) for g in grads.values()), default=0.0)
    return Target(record.key, reason, flat.size, one_sided, step, (weighted, raw))


def repair(
    loaded: LoadedScene,
    objectives: Sequence[Objective],
    result: AdjointResult,
    settings: RepairSpec,
    *,
    seed: int,
    spp: int,
    batches: int = 1,
    shard: int | None = None,
    passes: int | None = None,
    progress: Progress,
    stages_after: int = 0,
    until_resolved: bool = False,
) -> AdjointResult:
    """``result`` with every known-wrong gradient the budget allows computed again.

    ``seed``, ``spp``, ``batches`` and ``passes`` (backward passes per batch) are the whole
    job's, so shard i (``shard``: its 0-based batch index) renders exactly the seeds of batch
    i-1 of the whole run and their merge is that run's buffer. ``until_resolved`` (a whole run
    with render.until): rounds of seeds are added while a repaired sign is unresolved."""
    zeros = result.checks.zero_components if result.checks is not None else {}
    reasons = candidates(loaded, result.params, zeros)
    count = max(settings.seeds, batches)  # with batches, at least one seed each
    width, height = loaded.resolution
    whole = plan(
        reasons, result.params, result.values, result.grads, settings,
        pixels=width * height, spp=spp,
        passes=passes or len(integrator_plan(loaded)) * len(objectives),
        seeds=[derived_seed(seed, "repair", i) for i in range(count)], batches=batches,
    )  # fmt: skip
    chosen = whole if shard is None else replace(whole, seeds=whole.seeds[shard::batches])
    progress.plan(len(chosen.targets) + stages_after)
    repairs = {}
    for index, target in enumerate(chosen.targets, 1):
        label = (
            f"repair {index}/{len(chosen.targets)} {target.key}: differences over "
            f"{len(chosen.seeds)} seeds at {chosen.spp} spp"
        )
        with progress.stage(f"repair_{index}_s", label):
            repairs[target.key] = _differences(loaded, objectives, result, chosen, target)
    extra = Extra()
    if until_resolved and shard is None:  # a shard cannot know what the others resolved
        more = Rounds(seed, count, batches if batches > 1 else len(chosen.seeds), width * height)
        for target in chosen.targets:
            repairs[target.key] = _until_resolved(
                loaded, objectives, result, chosen, target, repairs[target.key], more, extra,
                progress, stages_after,
            )  # fmt: skip
    grads, statistics = _stored(result, repairs, batches)
    figures = _figures(chosen, settings, repairs, extra)
    return replace(
        result,
        grads=grads,
        statistics=statistics,
        params=tuple(_relabel(r, reasons, repairs, chosen) for r in result.params),
        repairs=repairs,
        provenance={**result.provenance, "repairs": figures},
    )


@dataclass
class Rounds:
    """Where the next round of a repair's extra seeds starts, and how many a round holds (one
    per batch, so that seed j stays in batch j mod k)."""

    seed: int
    next_index: int
    size: int
    pixels: int


@dataclass
class Extra:
    """What the repairs spent beyond the plan to resolve their signs."""

    samples: int = 0
    renders: int = 0
    seeds: dict[str, int] = field(default_factory=dict)  # key -> seeds added


def sign_resolved(fixed: Repair) -> bool:
    """Whether the sign of Σ_c ∂M/∂θ_c is resolved for every objective by the repair's seeds
    (Student-t 95 % with seeds − 1 dof); raw, not θ-weighted, so a θ of 0 can resolve too."""
    if not fixed.has_error:
        return False
    ones = np.ones(fixed.components)
    return all(
        fixed.significant(float(fixed.mean(name).sum()), fixed.signed_error(name, ones))
        for name in fixed.estimates
    )


def _until_resolved(
    loaded: LoadedScene,
    objectives: Sequence[Objective],
    result: AdjointResult,
    chosen: RepairPlan,
    target: Target,
    fixed: Repair,
    rounds: Rounds,
    extra: Extra,
    progress: Progress,
    stages_after: int,
) -> Repair:
    """``fixed`` with rounds of new seeds added while its sign is unresolved and what is left of
    ``repair.budget`` pays for a round (render.until's rule for batches, applied to seeds)."""
    cost = (chosen.spp * rounds.pixels + RENDER_OVERHEAD) * renders_per_seed([target])
    while (
        chosen.spp >= 1
        and not sign_resolved(fixed)
        and chosen.samples + extra.samples + cost * rounds.size <= chosen.budget_samples
        and len(fixed.seeds) + rounds.size <= MAX_SEEDS
    ):
        first, rounds.next_index = rounds.next_index, rounds.next_index + rounds.size
        seeds = tuple(
            derived_seed(rounds.seed, "repair", i) for i in range(first, rounds.next_index)
        )
        label = f"repair {target.key}: sign unresolved, {len(seeds)} more seeds"
        progress.plan(1 + stages_after)
        with progress.stage(f"repair_more_{first}_s", label):
            more = _differences(loaded, objectives, result, replace(chosen, seeds=seeds), target)
        fixed = replace(
            fixed,
            spp=fixed.spp + more.spp,
            seeds=fixed.seeds + more.seeds,
            estimates={
                n: np.concatenate([e, more.estimates[n]]) for n, e in fixed.estimates.items()
            },
            seconds=round(fixed.seconds + more.seconds, 4),
        )
        extra.samples += cost * rounds.size
        extra.renders += renders_per_seed([target]) * rounds.size
        extra.seeds[target.key] = extra.seeds.get(target.key, 0) + rounds.size
    return fixed


def _differences(
    loaded: LoadedScene,
    objectives: Sequence[Objective],
    result: AdjointResult,
    chosen: RepairPlan,
    target: Target,
) -> Repair:
    """Every seed's estimate of every component, for every objective; each side set once and
    rendered at every seed."""
    started = time.perf_counter()
    shape = result.values[target.key].shape
    theta = result.values[target.key].astype(np.float32).ravel()

    def measure(seed: int) -> np.ndarray:
        interrupts.raise_if_stopped()  # between renders: a stop is acted on within one render
        image = render_primal(loaded, chosen.spp, seed)
        return np.array([value_and_adjoint(loaded.mi, o, image)[0] for o in objectives])

    base: dict[int, np.ndarray] = {}  # M at θ, shared by every one-sided component
    rows = np.zeros((len(chosen.seeds), target.components, len(objectives)))
    try:
        away = dict(target.one_sided)  # component -> the sign of h, away from its bound
        for c in range(target.components):
            h = target.step * max(1.0, abs(float(theta[c]))) * away.get(c, 1)
            sides = []
            for multiple in (1, 2) if c in away else (1, -1):
                moved = theta.copy()
                moved[c] += multiple * h
                assign(loaded, target.key, moved.reshape(shape))
                sides.append(np.array([measure(seed) for seed in chosen.seeds]))
            if c in away:
                assign(loaded, target.key, theta.reshape(shape))
                for seed in chosen.seeds:
                    base[seed] = base[seed] if seed in base else measure(seed)
                at_base = np.array([base[seed] for seed in chosen.seeds])
                rows[:, c] = (4 * sides[0] - sides[1] - 3 * at_base) / (2 * h)
            else:
                rows[:, c] = (sides[0] - sides[1]) / (2 * h)
    finally:
        assign(loaded, target.key, theta.reshape(shape))
    names = [o.spec.name for o in objectives]
    return Repair(
        reason=target.reason,
        step=target.step,
        spp=(chosen.spp,) * len(chosen.seeds),
        seeds=chosen.seeds,
        one_sided=target.one_sided,
        estimates={name: rows[:, :, j] for j, name in enumerate(names)},
        reverse={name: result.grads[name][target.key].astype(np.float64).ravel() for name in names},
        seconds=round(time.perf_counter() - started, 4),
    )


def _stored(
    result: AdjointResult, repairs: dict[str, Repair], batches: int
) -> tuple[dict[str, dict[str, np.ndarray]], Any]:
    """The gradients with the repairs in place: the mean over seeds; with batch statistics,
    seed i counts in batch i mod k and the mean is the batches' spp-weighted one."""
    grads = {name: dict(per_key) for name, per_key in result.grads.items()}
    statistics = result.statistics
    keys = [r.key for r in result.params]
    for key, fixed in repairs.items():
        shape = result.values[key].shape
        if statistics is None:
            for name in grads:
                grads[name][key] = fixed.mean(name).astype(np.float32).reshape(shape)
            continue
        # float32 per batch, as a shard stores it: the merge of shards gives the same bits
        per_batch = {
            name: [rows[b::batches].mean(axis=0).astype(np.float32).reshape(shape)
                   for b in range(batches)]
            for name, rows in fixed.estimates.items()
        }  # fmt: skip
        theta = result.values[key].astype(np.float64)
        statistics, means = with_batch_estimates(statistics, keys, key, per_batch, theta)
        for name, mean in means.items():
            grads[name][key] = mean
    return grads, statistics


def _relabel(
    record: ParamRecord, reasons: dict[str, str], repairs: dict[str, Repair], chosen: RepairPlan
) -> ParamRecord:
    if record.key in repairs:
        entry = repair_entry(record.plugin, record.type)
        was = f"{record.trust}" + (f": {record.note}" if record.note else "")
        how = f"repaired by finite differences (reverse mode was {was})"
        if record.trust == "verified":  # a verified kind, repaired for this scene's reason
            how = f"repaired by finite differences ({reasons[record.key]})"
        note = how if entry.trust == "verified" else f"{entry.note}; {how}"
        return replace(record, estimator="finite-difference", trust=entry.trust, note=note)
    if record.key in chosen.skipped:  # known wrong and left as it is: say both
        known = record.note or reasons[record.key]
        if record.trust == "verified":  # a composite over a smooth lobe, the table's verified
            record = replace(record, trust="unverified")
            known = reasons[record.key]
        return replace(record, note=f"{known}; not repaired: {chosen.skipped[record.key]}")
    return record


def _figures(
    chosen: RepairPlan, settings: RepairSpec, repairs: dict[str, Repair], extra: Extra
) -> dict:
    """What the buffer's provenance says of the repairs (docs/buffer-format.md)."""
    return {
        "budget": settings.budget,
        "budget_samples": chosen.budget_samples,
        "samples": chosen.samples + extra.samples,
        "spp": chosen.spp,
        "seeds": list(chosen.seeds),
        "renders": renders_per_seed(chosen.targets) * len(chosen.seeds) + extra.renders,
        "repaired": [t.key for t in chosen.targets],
        "not_repaired": dict(chosen.skipped),
        "seconds": round(sum(r.seconds for r in repairs.values()), 4),
        "added_seeds": dict(extra.seeds),  # key -> seeds added while its sign was unresolved
        "unresolved": [key for key, fixed in repairs.items() if not sign_resolved(fixed)],
    }
