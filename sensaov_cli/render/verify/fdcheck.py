"""Check reverse-mode gradients against central finite differences, one parameter per kind.

For each (plugin, type) pair in the buffer's selection, one representative parameter is pushed
along a direction v (all components; a central block of texels for textures). Per seed s, the
adjoint's directional derivative <dM/dθ, v> at seed s is compared with
(M(θ + εv) − M(θ − εv)) / 2ε rendered at the same seed s (common random numbers), through the
integrator that computed the gradient (prb, or path for delta lobes: ``trust``). Over several
seeds the mean difference and its standard error decide: agrees, disagrees, or inconclusive
(noise too large to tell). Parameters whose sampling depends on them (roughness, eta, the
lobe weights of plastics) are only checkable on average: :func:`check_parameter_independent`
renders the two sides with independent seeds at a higher sample count.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass

import numpy as np

from sensaov_cli.buffer.model import ParamRecord
from sensaov_cli.errors import SpecError
from sensaov_cli.render.adjoint import (
    backward_pass,
    chunk_seed,
    path_chunks,
    path_integrator,
    render_primal,
)
from sensaov_cli.render.loading import LoadedScene, assign
from sensaov_cli.render.objectives import Objective, value_and_adjoint
from sensaov_cli.vocabulary import Trust

RELATIVE_TOLERANCE = 0.05  # agreement of the means, relative to the finite difference
NOISE_SIGMAS = 3.0  # a difference within 3 standard errors is consistent with noise
# "disagrees" needs more: the standard error comes from few seeds (6 by default), so the gap
# over it follows Student's t with seeds - 1 degrees of freedom, and a check runs one test per
# parameter kind. The threshold is t's two-sided 99.9 % point: at 6 seeds 6.87, not 3 (with 3,
# about one demo check in five failed a parameter that 12 seeds at 256 spp then confirmed).
_T_999 = {1: 636.6, 2: 31.6, 3: 12.9, 4: 8.61, 5: 6.87, 6: 5.96, 7: 5.41, 8: 5.04, 9: 4.78,
          10: 4.59, 11: 4.44, 12: 4.32, 15: 4.07, 20: 3.85, 30: 3.65}  # fmt: skip


def disagreement_sigmas(seeds: int) -> float:
    """The t threshold for ``seeds`` seeds (the next tabulated degrees of freedom below)."""
    dof = max(seeds - 1, 1)
    return _T_999[max(d for d in _T_999 if d <= dof)] if dof <= 30 else 3.29


MAX_RELATIVE_NOISE = 0.25  # above this standard error (relative) a check is inconclusive
# Step of independent-seed differences, relative to max(1, |θ|): their noise grows as 1/ε,
# their curvature bias as ε² (a rough dielectric's eta: 7 % at 0.05, 1 % at 0.02, measured).
INDEPENDENT_STEP = 0.02


@dataclass(frozen=True)
class GradientCheck:
    key: str
    plugin: str
    type: str
    claimed: Trust  # what the trust table says for this kind of parameter
    adjoint: float  # mean over seeds of <dM/dθ, v>
    finite_difference: float  # mean over seeds of the central difference
    standard_error: float  # of the mean difference (0 for one same-seed comparison)
    verdict: str  # "agrees" | "disagrees" | "inconclusive"
    method: str = "seeds"  # "seeds": means over seeds; "same seed": one, to float precision

    @property
    def claimed_verified(self) -> bool:
        return self.claimed == "verified"

    @property
    def relative_error(self) -> float:
        return abs(self.adjoint - self.finite_difference) / max(abs(self.finite_difference), 1e-30)


def representatives(loaded: LoadedScene) -> list[ParamRecord]:
    """The first selected parameter of each (plugin, type, texture?) kind."""
    seen: dict[tuple[str, str, bool], ParamRecord] = {}
    for info in loaded.selected:
        seen.setdefault((info.plugin, info.type, info.is_texture), info)
    return list(seen.values())


def direction(info: ParamRecord) -> np.ndarray:
    v = np.ones(info.shape, np.float32)
    if info.is_texture and len(info.shape) >= 2:
        v[:] = 0  # a block of texels, so the check exercises the UV lookup, not just the mean
        h, w = info.shape[:2]
        v[h // 4 : max(h // 4 + 1, 3 * h // 4), w // 4 : max(w // 4 + 1, 3 * w // 4)] = 1
    return v


def adjoint_along(
    loaded: LoadedScene, objective: Objective, info: ParamRecord, v: np.ndarray, spp: int, seed: int
) -> float:
    """<dM/dθ, v> from a primal and a backward pass at ``seed``, as a run computes it."""
    _, adjoint_image = value_and_adjoint(loaded.mi, objective, render_primal(loaded, spp, seed))
    integrator = loaded.routes[info.key]
    grads = backward_pass(loaded, integrator, {info.key}, adjoint_image, spp, seed)
    return float((grads[info.key] * v).sum())


def objective_like_backward(
    loaded: LoadedScene, objective: Objective, info: ParamRecord, spp: int, seed: int
) -> float:
    """M rendered with the samples the backward pass of ``info`` at ``seed`` uses."""
    if loaded.routes[info.key] == "prb":
        image = render_primal(loaded, spp, seed)
    else:  # path's chunks, each its share of spp (adjoint._path_backward)
        path = path_integrator(loaded)
        width, height = loaded.resolution
        chunks = path_chunks(width * height, spp)
        image = sum(
            render_primal(loaded, chunk, chunk_seed(seed, index), path) * (chunk / spp)
            for index, chunk in enumerate(chunks)
        )
    value, _ = value_and_adjoint(loaded.mi, objective, image)
    return value


def check_parameter(
    loaded: LoadedScene, objective: Objective, info: ParamRecord, *, spp: int, seeds: list[int]
) -> GradientCheck:
    """Same-seed central differences, ε = 1e-2 · max(1, |θ|)."""
    theta = np.array(loaded.params[info.key], dtype=np.float32).reshape(info.shape)
    v = direction(info)
    eps = 1e-2 * max(1.0, float(np.abs(theta).max()))
    adjoints, differences = [], []
    try:
        for seed in seeds:
            adjoints.append(adjoint_along(loaded, objective, info, v, spp, seed))
            sides = []
            for sign in (1, -1):
                assign(loaded, info.key, theta + sign * eps * v)
                sides.append(objective_like_backward(loaded, objective, info, spp, seed))
            assign(loaded, info.key, theta)
            differences.append((sides[0] - sides[1]) / (2 * eps))
    finally:
        assign(loaded, info.key, theta)
    return judge(info, np.array(adjoints), np.array(differences))


def check_parameter_independent(
    loaded: LoadedScene,
    objective: Objective,
    info: ParamRecord,
    *,
    spp: int,
    fd_spp: int,
    seeds: list[int],
) -> GradientCheck:
    """Differences of independent renders at ``fd_spp`` (step INDEPENDENT_STEP · max(1, |θ|)):
    the reference where θ changes which lobe or direction is sampled, so that the same seed
    does not give the same paths on both sides."""
    theta = np.array(loaded.params[info.key], dtype=np.float32).reshape(info.shape)
    v = direction(info)
    eps = INDEPENDENT_STEP * max(1.0, float(np.abs(theta).max()))
    adjoints, differences = [], []
    try:
        for seed in seeds:
            adjoints.append(adjoint_along(loaded, objective, info, v, spp, seed))
            sides = []
            for side, sign in enumerate((1, -1)):
                assign(loaded, info.key, theta + sign * eps * v)
                sides.append(
                    objective_like_backward(loaded, objective, info, fd_spp, 1000 + 2 * seed + side)
                )
            assign(loaded, info.key, theta)  # the next seed's adjoint is taken at θ
            differences.append((sides[0] - sides[1]) / (2 * eps))
    finally:
        assign(loaded, info.key, theta)
    return judge(info, np.array(adjoints), np.array(differences))


def judge(info: ParamRecord, adjoints: np.ndarray, differences: np.ndarray) -> GradientCheck:
    gap = adjoints - differences
    error = float(gap.std(ddof=1) / math.sqrt(len(gap))) if len(gap) > 1 else 0.0
    ad, fd = float(adjoints.mean()), float(differences.mean())
    scale = max(abs(fd), 1e-30)
    if (
        abs(ad - fd) <= max(RELATIVE_TOLERANCE * scale, NOISE_SIGMAS * error)
        and error <= MAX_RELATIVE_NOISE * scale
    ):
        verdict = "agrees"
    elif (
        abs(ad - fd) > disagreement_sigmas(len(gap)) * error
        and abs(ad - fd) > RELATIVE_TOLERANCE * scale
    ):
        verdict = "disagrees"
    else:
        verdict = "inconclusive"
    return GradientCheck(info.key, info.plugin, info.type, info.trust, ad, fd, error, verdict)


def check_gradients(
    loaded: LoadedScene,
    objective: Objective,
    *,
    spp: int,
    seeds: list[int],
    keys: list[str] | None = None,
) -> list[GradientCheck]:
    """One check per parameter kind, or of the named ``keys`` (each must be a selected key)."""
    chosen = representatives(loaded) if keys is None else named(loaded, keys)
    return [check_parameter(loaded, objective, info, spp=spp, seeds=seeds) for info in chosen]


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
