"""``sensaov check``'s comparisons: reverse-mode gradients against central finite differences,
and a stored buffer against forward mode.

A parameter is pushed along a direction v (all components; a central block of texels for
textures); per seed, <dM/dθ, v> is compared with (M(θ + εv) − M(θ − εv)) / 2ε rendered at the
same seed through the integrator that computed the gradient. ``sensaov check`` plans one
parameter per kind (plugin, type, texture or not), or the ``--key`` ones (:func:`plan_audit`):

- **one seed** where the value does not steer sampling (``trust.SAME_SEED_EXACT``) and cannot
  end a path: the difference reproduces the adjoint to float precision (SAME_SEED_TOLERANCE);
- **several seeds** where it does (roughness, eta, lobe and blend weights), and under Russian
  roulette for every value that changes a path's throughput (:func:`roulette`): each seed's gap
  is noise, so only its mean is judged (:func:`judge`); seeds whose gaps look heavy-tailed,
  or reverse mode far wider than the differences, are ``noisy``, never a disagreement;
- kinds the trust table calls biased, and near-specular ones (render/verify/tails.py), are
  repaired by ``sensaov run``: measured only when named or with ``--full``.

Every verdict but "agrees" carries its reason.

:func:`check_parameter` with ``fd_spp`` differences independent renders at more samples: the
trust table's reference where θ changes which paths are sampled (``scripts/trust_table.py``).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Container, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from sensaov_cli.buffer.forward_sidecar import DUALITY_FLOOR, duality_tolerance
from sensaov_cli.buffer.model import ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.statistics import heavy_tail
from sensaov_cli.errors import SpecError
from sensaov_cli.progress import Progress
from sensaov_cli.render.adjoint import (
    adjoint_images,
    backward_pass,
    forward_image,
    gradient_seed,
    image_like_backward,
    render_primal,
)
from sensaov_cli.render.loading import LoadedScene, assign
from sensaov_cli.render.objectives import Objective, value_and_adjoint
from sensaov_cli.render.verify.selfcheck import zero_effect
from sensaov_cli.render.verify.tails import near_specular
from sensaov_cli.render.verify.trust import SAME_SEED_EXACT
from sensaov_cli.vocabulary import Trust

RELATIVE_TOLERANCE = 0.05  # agreement of the means, relative to the finite difference
NOISE_SIGMAS = 3.0  # a difference within 3 standard errors is consistent with noise
# "disagrees" needs more: the gap over a standard error from few seeds follows Student's t with
# seeds - 1 degrees of freedom, one test per kind: its two-sided 99.9 % point.
_T_999 = {1: 636.6, 2: 31.6, 3: 12.9, 4: 8.61, 5: 6.87, 6: 5.96, 7: 5.41, 8: 5.04, 9: 4.78,
          10: 4.59, 11: 4.44, 12: 4.32, 15: 4.07, 20: 3.85, 30: 3.65}  # fmt: skip


def disagreement_sigmas(seeds: int) -> float:
    """The t threshold for ``seeds`` seeds (the next tabulated degrees of freedom below)."""
    dof = max(seeds - 1, 1)
    return _T_999[max(d for d in _T_999 if d <= dof)] if dof <= 30 else 3.29


MAX_RELATIVE_NOISE = 0.25  # above this standard error (relative) a check is inconclusive
# Too noisy to judge, and reverse mode this much wider spread than the differences at the same
# seeds: its per-path derivative is heavy-tailed (a near-specular lobe: hundreds of times), not
# merely undersampled (ordinary kinds: within a few times).
NOISY_SPREAD = 10.0
# Step of independent-seed differences, relative to max(1, |θ|): noise grows as 1/ε, curvature
# bias as ε².
INDEPENDENT_STEP = 0.02
STEP = 1e-2  # of same-seed differences: ε = STEP · max(1, |θ|)
SAME_SEED_TOLERANCE = 2e-3  # relative gap of one same-seed comparison (module docstring)
# M is a float32 mean: each side carries about this relative rounding, divided by 2ε.
FLOAT_ROUNDING = 4 * 2.0**-24


@dataclass(frozen=True)
class GradientCheck:
    key: str
    plugin: str
    type: str
    claimed: Trust  # what the trust table says for this kind of parameter
    adjoint: float  # mean over seeds of <dM/dθ, v>
    finite_difference: float  # mean over seeds of the central difference
    standard_error: float  # of the mean difference (0 for one same-seed comparison)
    verdict: str  # "agrees" | "disagrees" | "inconclusive" | "noisy"
    method: str = "seeds"  # "seeds": means over seeds; "same seed": one, to float precision
    reason: str = ""  # why, for every verdict but "agrees"

    @property
    def claimed_verified(self) -> bool:
        return self.claimed == "verified"

    @property
    def relative_error(self) -> float:
        return abs(self.adjoint - self.finite_difference) / max(abs(self.finite_difference), 1e-30)


def representatives(loaded: LoadedScene, avoid: Container[str] = ()) -> list[ParamRecord]:
    """The first selected parameter of each (plugin, type, texture?) kind, one not in ``avoid``
    where the kind has one."""
    seen: dict[tuple[str, str, bool], ParamRecord] = {}
    for info in loaded.selected:
        kind = (info.plugin, info.type, info.is_texture)
        if kind not in seen or (seen[kind].key in avoid and info.key not in avoid):
            seen[kind] = info
    return list(seen.values())


def direction(info: ParamRecord) -> np.ndarray:
    v = np.ones(info.shape, np.float32)
    if info.is_texture and len(info.shape) >= 2:
        v[:] = 0  # a block of texels, so the check exercises the UV lookup, not just the mean
        h, w = info.shape[:2]
        v[h // 4 : max(h // 4 + 1, 3 * h // 4), w // 4 : max(w // 4 + 1, 3 * w // 4)] = 1
    return v


def difference(
    loaded: LoadedScene,
    info: ParamRecord,
    v: np.ndarray,
    step: float,
    spp: int,
    seeds: tuple[int, int],
    measure: Callable[[Any], Any],
) -> Any:
    """(f(θ + εv) − f(θ − εv)) / 2ε, ε = ``step`` · max(1, |θ|), f the ``measure`` of the image
    rendered at each side's seed as the backward pass of ``info`` is; θ is restored."""
    theta = np.array(loaded.params[info.key], dtype=np.float32).reshape(info.shape)
    eps = step * max(1.0, float(np.abs(theta).max()))
    sides = []
    try:
        for seed, sign in zip(seeds, (1, -1), strict=True):
            assign(loaded, info.key, theta + sign * eps * v)
            sides.append(measure(image_like_backward(loaded, loaded.routes[info.key], spp, seed)))
    finally:
        assign(loaded, info.key, theta)
    return (sides[0] - sides[1]) / (2 * eps)


def central_difference(
    loaded: LoadedScene,
    objective: Objective,
    info: ParamRecord,
    step: float,
    spp: int,
    seeds: tuple[int, int],
) -> float:
    """The :func:`difference` of M along v = :func:`direction`."""

    def measure(image: Any) -> float:
        return value_and_adjoint(loaded.mi, objective, image)[0]

    return float(difference(loaded, info, direction(info), step, spp, seeds, measure))


def check_parameter(
    loaded: LoadedScene,
    objective: Objective,
    info: ParamRecord,
    *,
    spp: int,
    seeds: list[int],
    fd_spp: int | None = None,
) -> GradientCheck:
    """Same-seed central differences, ε = STEP · max(1, |θ|); with ``fd_spp``, differences of
    independent renders at ``fd_spp``: the reference where θ changes which paths are sampled."""
    (check,) = check_parameters(loaded, objective, [info], spp=spp, seeds=seeds, fd_spp=fd_spp)
    return check


def check_parameters(
    loaded: LoadedScene,
    objective: Objective,
    infos: Sequence[ParamRecord],
    *,
    spp: int,
    seeds: list[int],
    fd_spp: int | None = None,
) -> list[GradientCheck]:
    """:func:`check_parameter` of each of ``infos``; their adjoints come from one primal and one
    backward pass per integrator and seed for all of them, as a run computes them."""
    adjoints: dict[str, list[float]] = {info.key: [] for info in infos}
    for seed in seeds:
        for key, along in _adjoints(loaded, objective, infos, spp, seed)[1].items():
            adjoints[key].append(along)
    checks = []
    for info in infos:
        differences = []
        for seed in seeds:
            if fd_spp is None:
                fd = central_difference(loaded, objective, info, STEP, spp, (seed, seed))
            else:
                sides = (1000 + 2 * seed, 1001 + 2 * seed)
                fd = central_difference(loaded, objective, info, INDEPENDENT_STEP, fd_spp, sides)
            differences.append(fd)
        checks.append(judge(info, np.array(adjoints[info.key]), np.array(differences)))
    return checks


def judge(info: ParamRecord, adjoints: np.ndarray, differences: np.ndarray) -> GradientCheck:
    """The verdict on the means over seeds: noisy where the seeds' gaps look heavy-tailed
    (their standard error is then no measure of the gap), else by the rules of the table in
    docs/verification.md."""
    gap = adjoints - differences
    error = float(gap.std(ddof=1) / math.sqrt(len(gap))) if len(gap) > 1 else 0.0
    ad, fd = float(adjoints.mean()), float(differences.mean())
    scale = max(abs(fd), 1e-30)
    sigmas = disagreement_sigmas(len(gap))
    # The gaps, not each side: at a shared seed the two sides share their noise, however wild;
    # and a tail of gaps each within the tolerance changes no verdict.
    small = float(np.abs(gap).max()) <= RELATIVE_TOLERANCE * scale
    tails = None if small else heavy_tail(gap)
    spread = _spread_ratio(adjoints, differences)
    reason = ""
    if tails is not None:
        verdict = "noisy"
        reason = f"reverse mode minus the differences over {len(gap)} seeds: {tails}"
    elif spread > NOISY_SPREAD and error > MAX_RELATIVE_NOISE * scale:
        verdict = "noisy"
        reason = (
            f"reverse mode's estimates spread {spread:.0f}x wider over {len(gap)} seeds than "
            "central differences at the same seeds: its derivative is carried by a few rare "
            "paths (heavy-tailed), so no number of seeds here can judge it"
        )
    elif (
        abs(ad - fd) <= max(RELATIVE_TOLERANCE * scale, NOISE_SIGMAS * error)
        and error <= MAX_RELATIVE_NOISE * scale
    ):
        verdict = "agrees"
    elif abs(ad - fd) > sigmas * error and abs(ad - fd) > RELATIVE_TOLERANCE * scale:
        verdict = "disagrees"
        reason = (
            f"the gap is {abs(ad - fd) / max(error, 1e-300):.1f} standard errors, beyond "
            f"{sigmas:.2f} (Student's t at 99.9 %, {len(gap)} seeds), and "
            f"{abs(ad - fd) / scale:.0%} of the finite difference"
        )
    else:
        verdict = "inconclusive"
        reason = _why_inconclusive(abs(ad - fd), error, scale, sigmas)
    return GradientCheck(
        info.key, info.plugin, info.type, info.trust, ad, fd, error, verdict, reason=reason
    )


def _spread_ratio(adjoints: np.ndarray, differences: np.ndarray) -> float:
    """How many times wider reverse mode's estimates spread over seeds than the differences'."""
    if len(adjoints) < 2:
        return 0.0
    return float(adjoints.std(ddof=1) / max(float(differences.std(ddof=1)), 1e-300))


def _why_inconclusive(gap: float, error: float, scale: float, sigmas: float) -> str:
    if error > MAX_RELATIVE_NOISE * scale:
        return (
            f"too noisy: the standard error is {error / scale:.0%} of the finite difference "
            f"(at most {MAX_RELATIVE_NOISE:.0%} to agree): raise --spp or --seeds"
        )
    return (
        f"the gap is {gap / max(error, 1e-300):.1f} standard errors: more than "
        f"{NOISE_SIGMAS:g} to agree, not {sigmas:.2f} to disagree: raise --spp or --seeds"
    )


def roulette(loaded: LoadedScene) -> str | None:
    """Why path termination depends on throughput (Russian roulette starts before the last
    bounce), so a parameter that changes throughput changes which paths end at one seed; None
    where it cannot."""
    rr_depth = getattr(loaded.integrator, "rr_depth", None)
    max_depth = getattr(loaded.integrator, "max_depth", None)
    if rr_depth is None or max_depth is None:
        return None
    unbounded = max_depth < 0 or max_depth >= 0xFFFFFFFF
    if not unbounded and rr_depth >= max_depth:
        return None
    shown = "unbounded" if unbounded else str(max_depth)
    return (
        f"Russian roulette (rr_depth {rr_depth} < max_depth {shown}) ends paths by their "
        "throughput, so one seed's difference is no reference for a value that changes it: "
        "compared over seeds"
    )


def named(loaded: LoadedScene, keys: list[str]) -> list[ParamRecord]:
    by_key = {info.key: info for info in loaded.selected}
    for key in keys:
        if key not in by_key:
            close = difflib.get_close_matches(key, sorted(by_key), n=1)
            raise SpecError(
                f"{key!r} is not a selected parameter",
                where="--key",
                hint=f"did you mean {close[0]!r}?" if close else "'sensaov params JOB' lists them",
            )
    return [by_key[key] for key in dict.fromkeys(keys)]


# --- sensaov check: one seed where it suffices, several where it must ---------------------------


@dataclass(frozen=True)
class AuditPlan:
    one_seed: tuple[ParamRecord, ...]
    seeds: tuple[ParamRecord, ...]
    skipped: tuple[tuple[str, str], ...]  # (key, why it is not measured)
    notes: tuple[str, ...] = ()  # what changed the plan (Russian roulette)


def plan_audit(loaded: LoadedScene, keys: Sequence[str] | None, full: bool) -> AuditPlan:
    """Which kinds one seed checks, which need seeds, which are not measured (and why)."""
    heavy = near_specular(loaded)
    zeros = zero_values(loaded)
    avoid = {*heavy, *zeros}
    chosen = representatives(loaded, avoid) if not keys else named(loaded, list(keys))
    rr = roulette(loaded)
    one, many, skipped, moved = [], [], [], False
    for info in chosen:
        exact = (info.plugin, info.type, info.is_texture) in SAME_SEED_EXACT
        if info.key in zeros:  # the run lowers its label: so does the claim checked here
            info = replace(info, trust="unverified", note=zeros[info.key])
        if info.trust in ("biased", "no_gradient") and not keys and not full:
            skipped.append((info.key, f"{info.plugin} {info.type}: {info.trust} in the trust "
                            "table, so 'sensaov run' repairs it (--full measures it)"))  # fmt: skip
        elif info.key in avoid and not keys and not full:
            why = heavy.get(info.key) or zeros[info.key]
            skipped.append((info.key, f"{why}: 'sensaov run' repairs or labels it (--full "
                            "measures reverse mode)"))  # fmt: skip
        elif exact and not full and (rr is None or info.type == "radiance"):
            one.append(info)  # an emitter's radiance changes no throughput
        else:
            moved = moved or (exact and not full)
            many.append(info)
    notes = (rr,) if rr is not None and moved else ()
    return AuditPlan(tuple(one), tuple(many), tuple(skipped), notes)


def zero_values(loaded: LoadedScene) -> dict[str, str]:
    """key -> why, for parameters with a value exactly 0 in a slot where reverse mode loses
    the derivative there (render/verify/selfcheck.py, check (b)): the run labels them."""
    found = {}
    for info in loaded.selected:
        effect = zero_effect(info.plugin, info.type)
        if effect is not None:
            count = int(np.count_nonzero(np.asarray(loaded.params[info.key]) == 0))
            if count:
                found[info.key] = f"value exactly 0 in {count} components ({effect})"
    return found


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
                fd = central_difference(loaded, objective, info, STEP, spp, (seed, seed))
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
    for info in infos:  # the run's own route: composites send some children to path
        groups.setdefault(loaded.routes[info.key], set()).add(info.key)
    grads: dict[str, np.ndarray] = {}
    for integrator, keys in groups.items():
        grads.update(backward_pass(loaded, integrator, keys, adjoint_image, spp, seed))
    return value, {i.key: float((grads[i.key] * direction(i)).sum()) for i in infos}


def _one_seed(
    info: ParamRecord, adjoints: list[float], differences: list[float], value: float
) -> GradientCheck:
    """Agreement to float precision at one seed; a gap beyond 5 % disagrees; between them,
    inconclusive (a path that changed between the sides: --full compares over seeds)."""
    ad, fd = adjoints[0], differences[0]
    floor = FLOAT_ROUNDING * abs(value) / (2 * STEP)  # the largest ε is never smaller
    gap = abs(ad - fd)
    relative = gap / max(abs(fd), 1e-30)
    reason = ""
    if gap <= max(SAME_SEED_TOLERANCE * abs(fd), floor):
        verdict = "agrees"
    elif gap > max(RELATIVE_TOLERANCE * abs(fd), floor):
        verdict = "disagrees"
        reason = f"at the same seed the two differ by {relative:.1%} (more than 5 %)"
    else:
        verdict = "inconclusive"
        reason = (
            f"at the same seed the two differ by {relative:.2%}: more than float rounding, "
            "less than a disagreement (a path changed between the sides: --full compares over "
            "seeds)"
        )
    return GradientCheck(
        info.key, info.plugin, info.type, info.trust, ad, fd, 0.0, verdict, "same seed", reason
    )


# --- a stored buffer against forward mode (docs/verification.md, "Forward/reverse duality"):
# per objective, key and direction v (ones, then seeded Gaussian ones), at the buffer's gradient
# seed, reverse ⟨g, v⟩ from the stored gradient against forward ⟨dM/dI, J·v⟩: equal up to float32
# rounding, so a larger gap is a corrupt or stale buffer and fails whatever the trust label. When
# asked, the central difference of the image at that seed checks Mitsuba's derivative itself,
# within FD_TOLERANCE; it fails only a verified parameter ("n/a" where discontinuous).

# Same-seed central differences (STEP): 2 % leaves room for a path that crosses a
# light's edge between the two sides.
FD_TOLERANCE = 0.02
_TINY = 1e-30


@dataclass(frozen=True)
class DualityCheck:
    objective: str
    key: str
    direction: str  # "ones" or "random <n>"
    trust: Trust
    reverse: float
    forward: float
    central: float | None  # None: not checkable at one seed (discontinuous), or not asked for
    seed: int
    tolerance: float = DUALITY_FLOOR  # of the duality residual, for this image and spp
    central_asked: bool = True  # False: the quick check leaves central differences out

    @property
    def duality_error(self) -> float:
        return abs(self.forward - self.reverse) / max(abs(self.reverse), _TINY)

    @property
    def central_error(self) -> float | None:
        if self.central is None:
            return None
        return abs(self.forward - self.central) / max(abs(self.central), _TINY)

    @property
    def verdict(self) -> str:
        if self.duality_error > self.tolerance and abs(self.forward - self.reverse) > _TINY:
            return "BUFFER DISAGREES"
        error = self.central_error
        if error is not None and error > FD_TOLERANCE:
            return "fd disagrees" if self.trust != "verified" else "FD DISAGREES"
        return "agrees"

    @property
    def failed(self) -> bool:
        return self.verdict.isupper()


def top_keys(buffer: SensitivityBuffer, objective: str, k: int) -> list[str]:
    """The ``k`` keys with the largest ‖θ · g‖ (parameters with no gradient left out); a
    repaired parameter by its reverse-mode gradient, which is the one checked."""
    scores = {
        p.key: float(np.linalg.norm(buffer.value(p.key) * buffer.reverse_grad(objective, p.key)))
        for p in buffer.params
        if p.trust != "no_gradient"
    }
    return sorted((key for key in scores if scores[key] > 0), key=lambda k_: -scores[k_])[:k]


def directions(info: ParamRecord, count: int, seed: int) -> list[tuple[str, np.ndarray]]:
    """Ones, then ``count`` Gaussian directions (seeded: the same every run)."""
    rng = np.random.default_rng(seed)
    randoms = [rng.standard_normal(info.shape).astype(np.float32) for _ in range(count)]
    return [("ones", np.ones(info.shape, np.float32))] + [
        (f"random {n + 1}", v) for n, v in enumerate(randoms)
    ]


def check_duality(
    loaded: LoadedScene,
    objectives: list[Objective],
    buffer: SensitivityBuffer,
    *,
    keys: list[str] | None,
    top: int,
    random_directions: int,
    progress: Progress,
    central: bool,
) -> list[DualityCheck]:
    """One row per (objective, key, direction), each a progress line; ``central``: also the
    central difference of the image (two renders a row)."""
    spp = int(buffer.provenance["spp"])
    # Each batch of the run replayed at its own (spp, seeds): its primal, its dM/dI.
    recorded = buffer.provenance.get("batches") or [
        {"spp": spp, "seed": buffer.provenance["primal_seed"]}
    ]
    batches = [(int(b["spp"]), int(b["seed"])) for b in recorded]
    replays = []
    for batch_spp, batch_seed in batches:
        primal = np.array(render_primal(loaded, batch_spp, batch_seed))
        replays.append((batch_spp, batch_seed, adjoint_images(loaded, objectives, primal)))
    records = {info.key: info for info in loaded.selected}  # ``keys``: checked by named
    tolerance = duality_tolerance(primal.shape[0] * primal.shape[1] * spp)
    rows: list[DualityCheck] = []
    for objective in objectives:
        name = objective.spec.name
        for key in keys or top_keys(buffer, name, top):
            for label, v in directions(records[key], random_directions, seed=len(rows)):
                stage = f"check: duality of {key} along {label} for '{name}'"
                with progress.stage(f"duality_{len(rows)}_s", stage):
                    rows.append(
                        _row(loaded, buffer, objective, records[key], label, v, replays, central)
                    )
    return [replace(row, tolerance=tolerance) for row in rows]


def _row(
    loaded: LoadedScene,
    buffer: SensitivityBuffer,
    objective_: Objective,
    info: ParamRecord,
    label: str,
    v: np.ndarray,
    replays: Sequence[tuple[int, int, dict[str, np.ndarray]]],
    asked: bool,
) -> DualityCheck:
    """The buffer's ⟨g, v⟩ against the batches' spp-weighted ⟨dM/dI_b, J_b·v⟩, each batch at
    its own spp and gradient seed (``replays``: (spp, primal seed, dM/dI per objective))."""
    objective = objective_.spec.name
    seed = buffer.objective(objective).grad_seed
    stored = buffer.reverse_grad(objective, info.key).astype(np.float64)  # forward's dual
    reverse = float(np.dot(stored.ravel(), v.ravel()))
    total = float(sum(batch_spp for batch_spp, _, _ in replays))
    forward, central = 0.0, None if not asked or "discontinuous" in info.flags else 0.0
    for batch_spp, primal_seed, adjoints in replays:
        adjoint, share = adjoints[objective], batch_spp / total
        at = gradient_seed(primal_seed, objective_.index)
        pushed = forward_image(loaded, {info.key: v}, spp=batch_spp, seed=at, shape=adjoint.shape)
        forward += share * (
            _weighted(adjoint, pushed.image) if pushed.image is not None else float("nan")
        )
        if central is not None:

            def image_at(image: Any) -> np.ndarray:
                return np.array(image, np.float32).astype(np.float64)

            moved = difference(loaded, info, v, STEP, batch_spp, (at, at), image_at)
            central += share * _weighted(adjoint, moved)
    record = buffer.param(info.key)
    # A repaired parameter's reverse mode is the one known wrong: its central difference may
    # disagree with forward mode without failing the check.
    trust = "biased" if record.estimator in ("finite-difference", "mixed") else record.trust
    return DualityCheck(
        objective, info.key, label, trust, reverse, forward, central, seed, central_asked=asked
    )


def _weighted(adjoint: np.ndarray, image: np.ndarray) -> float:
    return float((adjoint.astype(np.float64) * image.astype(np.float64)).sum())
