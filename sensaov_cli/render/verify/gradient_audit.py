"""``sensaov check``'s comparisons of reverse mode with finite differences, planned per kind.

One representative parameter per kind (plugin, type, texture or not), or the ``--key`` ones:

- **one seed** where the value does not steer sampling (``trust.SAME_SEED_EXACT``): at the
  reverse pass's own seed the primal is a smooth function of θ and the adjoint its derivative,
  so a central difference reproduces it to float precision (2e-3, Russian-roulette flips
  included; measured 8e-4 at most), whatever the seed or spp;
- **several seeds** where it does (roughness, eta, lobe and blend weights): each seed's adjoint
  and difference are unbiased, so their gap is noise and only its mean is judged
  (:func:`~.fdcheck.judge`);
- kinds the trust table knows to be biased are what ``sensaov run`` repairs: not measured
  unless named with ``--key`` or asked for with ``--full`` (every kind over every seed).

Per seed one primal and one backward pass per integrator give every chosen kind's adjoint;
each kind then costs the two renders of its difference. Each step is a progress line.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sensaov_cli.buffer.model import ParamRecord
from sensaov_cli.progress import Progress
from sensaov_cli.render.adjoint import backward_pass, render_primal
from sensaov_cli.render.loading import LoadedScene, assign
from sensaov_cli.render.objectives import Objective, value_and_adjoint
from sensaov_cli.render.verify.fdcheck import (
    RELATIVE_TOLERANCE,
    GradientCheck,
    direction,
    judge,
    named,
    objective_like_backward,
    representatives,
)
from sensaov_cli.render.verify.trust import SAME_SEED_EXACT, gradient_integrator

SAME_SEED_TOLERANCE = 2e-3  # relative gap of one same-seed comparison (module docstring)
STEP = 1e-2  # ε = STEP · max(1, |θ|), as fdcheck.check_parameter
# M is a float32 mean: each side carries about this relative rounding, divided by 2ε.
FLOAT_ROUNDING = 4 * 2.0**-24


@dataclass(frozen=True)
class AuditPlan:
    one_seed: tuple[ParamRecord, ...]
    seeds: tuple[ParamRecord, ...]
    skipped: tuple[tuple[str, str], ...]  # (key, why it is not measured)


def plan_audit(loaded: LoadedScene, keys: Sequence[str] | None, full: bool) -> AuditPlan:
    """Which kinds one seed checks, which need seeds, which are not measured (and why)."""
    chosen = representatives(loaded) if not keys else named(loaded, list(keys))
    one, many, skipped = [], [], []
    for info in chosen:
        if info.trust in ("biased", "no_gradient") and not keys and not full:
            skipped.append((info.key, f"{info.plugin} {info.type}: {info.trust} in the trust "
                            "table, so 'sensaov run' repairs it (--full measures it)"))  # fmt: skip
        elif (info.plugin, info.type, info.is_texture) in SAME_SEED_EXACT and not full:
            one.append(info)
        else:
            many.append(info)
    return AuditPlan(tuple(one), tuple(many), tuple(skipped))


def audit(
    loaded: LoadedScene,
    objective: Objective,
    plan: AuditPlan,
    *,
    spp: int,
    seeds: Sequence[int],
    progress: Progress,
) -> list[GradientCheck]:
    """The plan's comparisons: one-seed kinds at ``seeds[0]``, the others at every seed."""
    pairs: dict[str, tuple[list[float], list[float]]] = {}
    value = 0.0  # M at the first seed: the scale of its float32 rounding
    for index, seed in enumerate(seeds):
        infos = (plan.one_seed if index == 0 else ()) + plan.seeds
        if not infos:
            break
        tag = f"check: seed {index + 1}/{len(seeds)} at {spp} spp"
        with progress.stage(f"check_adjoint_{index}_s", f"{tag}: primal and backward passes"):
            measured, adjoints = _adjoints(loaded, objective, infos, spp, seed)
        value = measured if index == 0 else value
        for info in infos:
            label = f"{tag}: central difference of {info.plugin} {info.type} ({info.key})"
            with progress.stage(f"check_fd_{index}_{info.key}_s", label):
                fd = _difference(loaded, objective, info, spp, seed)
            adjoint_list, fd_list = pairs.setdefault(info.key, ([], []))
            adjoint_list.append(adjoints[info.key])
            fd_list.append(fd)
    checks = [_one_seed(info, *pairs[info.key], value) for info in plan.one_seed]
    return checks + [judge(i, *(np.array(side) for side in pairs[i.key])) for i in plan.seeds]


def _adjoints(
    loaded: LoadedScene, objective: Objective, infos: Sequence[ParamRecord], spp: int, seed: int
) -> tuple[float, dict[str, float]]:
    """M and <dM/dθ, v> of every parameter in ``infos`` from one primal and one backward pass
    per integrator at ``seed``, as a run computes them."""
    value, adjoint_image = value_and_adjoint(loaded.mi, objective, render_primal(loaded, spp, seed))
    groups: dict[str, set[str]] = {}
    for info in infos:
        groups.setdefault(gradient_integrator(info.plugin), set()).add(info.key)
    grads: dict[str, np.ndarray] = {}
    for integrator, keys in groups.items():
        grads.update(backward_pass(loaded, integrator, keys, adjoint_image, spp, seed))
    return value, {i.key: float((grads[i.key] * direction(i)).sum()) for i in infos}


def _difference(
    loaded: LoadedScene, objective: Objective, info: ParamRecord, spp: int, seed: int
) -> float:
    """(M(θ + εv) − M(θ − εv)) / 2ε, both sides with the backward pass's samples at ``seed``."""
    theta = np.array(loaded.params[info.key], dtype=np.float32).reshape(info.shape)
    v = direction(info)
    eps = STEP * max(1.0, float(np.abs(theta).max()))
    sides = []
    try:
        for sign in (1, -1):
            assign(loaded, info.key, theta + sign * eps * v)
            sides.append(objective_like_backward(loaded, objective, info, spp, seed))
    finally:
        assign(loaded, info.key, theta)
    return (sides[0] - sides[1]) / (2 * eps)


def _one_seed(
    info: ParamRecord, adjoints: list[float], differences: list[float], value: float
) -> GradientCheck:
    """Agreement to float precision at one seed; a gap beyond 5 % disagrees; between them,
    inconclusive (a path that changed between the sides: --full compares over seeds)."""
    ad, fd = adjoints[0], differences[0]
    floor = FLOAT_ROUNDING * abs(value) / (2 * STEP)  # the largest ε is never smaller
    gap = abs(ad - fd)
    if gap <= max(SAME_SEED_TOLERANCE * abs(fd), floor):
        verdict = "agrees"
    elif gap > max(RELATIVE_TOLERANCE * abs(fd), floor):
        verdict = "disagrees"
    else:
        verdict = "inconclusive"
    return GradientCheck(
        info.key, info.plugin, info.type, info.trust, ad, fd, 0.0, verdict, method="same seed"
    )
