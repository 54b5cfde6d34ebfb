"""Self-checks on the gradients a run computed, after its backward passes: no extra render.

They can only lower a parameter's trust label (docs/verification.md, "Run-time self-checks"):

(a) **no gradient flows**: a gradient identically 0 for every objective is ``no_gradient``.
(b) **zero components**: where a throughput weight (a reflectance, a medium's albedo) is exactly
    0, Mitsuba's replay has no later vertex to differentiate; where a medium's extinction is, it
    samples no interaction to differentiate: ∂M/∂θ there is wrong (θ·∂M/∂θ = 0 is right), so
    ``unverified`` (:func:`zero_effect`).
(c) **emission identities**, for objectives linear in the image: Σ θ·∂M/∂θ over an emitter's
    radiance-like parameters equals its ``scale`` (or spot texture) term, and summed over all
    emitters equals M. A violation beyond Monte Carlo error marks the parameters ``suspect``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import ParamRecord
from sensaov_cli.render.loading import LoadedScene
from sensaov_cli.render.objectives import Objective, value_and_adjoint
from sensaov_cli.render.verify.trust import NO_FLOW_REASON, known_zero_reason

LINEAR_OBJECTIVES = frozenset({"mean_luminance", "region_luminance"})
# Slots whose value multiplies a path's throughput: at 0 the path ends there.
THROUGHPUT_TYPES = frozenset({"reflectance", "specular", "transmittance", "albedo"})
# Slots of a medium's density (its extinction, and the scale on it): at 0 no interaction is
# sampled, so the replay misses what scattering there would add.
DENSITY_TYPES = frozenset({"sigma_t", "scale"})
MEDIA = frozenset({"homogeneous", "heterogeneous"})
# Same pass, same paths: an emitter's radiance and scale terms agree up to float32 accumulation.
PAIR_TOLERANCE = 1e-3
# M and its gradient-side estimate come from independent samples: the tolerance is
# MC_CONSTANT / sqrt(spp x effective pixels), never below 1 % (docs/verification.md).
MC_CONSTANT = 40.0
MIN_TOLERANCE = 0.01


@dataclass(frozen=True)
class EmitterTerms:
    """An emitter's parameters that its emission is proportional to, in two independent groups
    (``scale``: an envmap's scale, a spot light's varying texture); None where it has none, or
    one of its differentiable parameters is not selected."""

    name: str
    radiance: tuple[str, ...] | None
    scale: tuple[str, ...] | None


@dataclass(frozen=True)
class LinearObjective:
    value: float  # M at the primal
    effective_pixels: float  # (Σ w)² / Σ w² over the pixel weights of dM/dI


@dataclass(frozen=True)
class Identity:
    """One emission identity of check (c): its two sides and whether they agree."""

    objective: str
    check: str
    lhs: float
    rhs: float
    relative_difference: float
    tolerance: float
    passed: bool
    keys: tuple[str, ...]  # the parameters it involves
    summary: str


@dataclass(frozen=True)
class SelfCheck:
    params: tuple[ParamRecord, ...]  # the records with their labels after the checks
    no_gradient: tuple[str, ...]  # keys whose gradient is identically 0 for every objective
    zero_components: dict[str, int]  # key -> how many of its throughput components are 0
    identities: tuple[Identity, ...]

    def figures(self) -> dict[str, Any]:
        """What was checked and found, as the buffer's provenance records it."""
        return {
            "no_gradient": list(self.no_gradient),
            "zero_components": dict(self.zero_components),
            "emission_identities": [
                {**asdict(identity), "keys": list(identity.keys)} for identity in self.identities
            ],
        }


def check_gradients(
    records: Sequence[ParamRecord],
    values: Mapping[str, np.ndarray],
    grads: Mapping[str, Mapping[str, np.ndarray]],
    linear: Mapping[str, LinearObjective],
    emitters: Sequence[EmitterTerms],
    spp: int,
    integrators: Mapping[str, str],
) -> SelfCheck:
    """Apply checks (a), (b), (c) to a run's gradients; ``integrators``: key -> its integrator."""
    no_flow = [r.key for r in records if all(not np.any(g[r.key]) for g in grads.values())]
    zeros = {
        r.key: [int(i) for i in np.flatnonzero(values[r.key].ravel() == 0)]
        for r in records
        if zero_effect(r.plugin, r.type) and np.any(values[r.key] == 0)
    }
    identities = []
    for name, objective in linear.items():
        contributions = {r.key: _contribution(values[r.key], grads[name][r.key]) for r in records}
        identities += _identities(name, objective, contributions, emitters, spp)
    suspect: dict[str, list[str]] = {}
    for identity in identities:
        if not identity.passed:
            for key in identity.keys:
                suspect.setdefault(key, []).append(identity.summary)
    labelled = tuple(
        _label(r, values[r.key], integrators[r.key] if r.key in no_flow else None, zeros, suspect)
        for r in records
    )
    counts = {key: len(where) for key, where in zeros.items()}
    return SelfCheck(labelled, tuple(no_flow), counts, tuple(identities))


def _contribution(value: np.ndarray, grad: np.ndarray) -> float:
    return float(np.dot(value.astype(np.float64).ravel(), grad.astype(np.float64).ravel()))


def _label(
    record: ParamRecord,
    value: np.ndarray,
    no_flow: str | None,
    zeros: Mapping[str, list[int]],
    suspect: Mapping[str, list[str]],
) -> ParamRecord:
    """The record with the strongest finding: no gradient flowing through integrator
    ``no_flow``, then suspect, then zero components."""
    if no_flow is not None:
        all_zero = record.type in THROUGHPUT_TYPES and not np.any(value)  # no path continues
        reason = known_zero_reason(record.plugin, record.type, record.key, no_flow, all_zero)
        # a kind the table labels no_gradient keeps the table's reason
        note = record.note if record.trust == "no_gradient" else reason or NO_FLOW_REASON
        return replace(record, trust="no_gradient", note=note)
    if record.key in suspect:
        figures = "failed a self-check: " + "; ".join(suspect[record.key])
        if record.trust == "biased":  # already known wrong: keep the label, add the figures
            return replace(record, note=f"{record.note}; {figures}")
        return replace(record, trust="suspect", note=figures)
    if record.key in zeros and record.trust == "verified":
        why = zero_effect(record.plugin, record.type) or ""
        return replace(record, trust="unverified", note=_zeros_note(zeros[record.key], value, why))
    return record


def zero_effect(plugin: str, ptype: str) -> str | None:
    """What a value of exactly 0 in this slot does to the path Mitsuba replays, where it loses
    the derivative there (None: a zero that loses nothing, an emitter's radiance say)."""
    if ptype in THROUGHPUT_TYPES:
        return "zero throughput ends the path Mitsuba replays"
    if ptype in DENSITY_TYPES and plugin in MEDIA:
        return "at zero extinction Mitsuba samples no interaction, so it misses in-scattering"
    return None


def _zeros_note(where: list[int], value: np.ndarray, why: str) -> str:
    shown = f"components {where}" if len(where) <= 8 else f"{len(where)} components"
    return (
        f"value exactly 0 in {shown} of {value.size}: ∂M/∂θ there is not reliable ({why}); "
        "θ·∂M/∂θ there is 0 whatever the gradient"
    )


def tolerance(spp: int, effective_pixels: float) -> float:
    """Relative tolerance of Σ_emitters θ·∂M/∂θ against M (see MC_CONSTANT)."""
    return max(MIN_TOLERANCE, MC_CONSTANT / math.sqrt(max(spp * effective_pixels, 1.0)))


def _identity(
    objective: str, what: str, lhs: float, rhs: float, tol: float, keys: Sequence[str]
) -> Identity:
    scale = max(abs(lhs), abs(rhs))
    gap = (lhs - rhs) / scale if scale > 0 else 0.0
    summary = f"{what} for {objective!r}: {lhs:.4g} vs {rhs:.4g} ({gap:+.1%}, tolerance {tol:.1%})"
    return Identity(objective, what, lhs, rhs, gap, tol, abs(gap) <= tol, tuple(keys), summary)


def _identities(
    objective: str,
    linear: LinearObjective,
    contributions: Mapping[str, float],
    emitters: Sequence[EmitterTerms],
    spp: int,
) -> list[Identity]:
    def total(keys: Sequence[str]) -> float:
        return math.fsum(contributions[k] for k in keys)

    found = []
    for e in emitters:
        if e.radiance and e.scale:
            what = f"emitter {e.name!r}: Σθ·∂M/∂θ of its radiance vs of its scale"
            keys = [*e.radiance, *e.scale]
            found.append(
                _identity(objective, what, total(e.radiance), total(e.scale), PAIR_TOLERANCE, keys)
            )
    complete = [e.radiance or e.scale for e in emitters]
    if emitters and all(complete):
        keys = [k for group in complete for k in group or ()]
        tol = tolerance(spp, linear.effective_pixels)
        what = "Σθ·∂M/∂θ over every emitter's radiance vs M"
        found.append(_identity(objective, what, total(keys), linear.value, tol, keys))
    return found


# --- what the live scene says: which parameters each emitter's emission is proportional to ----

RADIANCE_SLOTS = frozenset({"radiance", "irradiance", "intensity", "data"})


def self_check(
    loaded: LoadedScene,
    objectives: Sequence[Objective],
    image: np.ndarray,
    values: Mapping[str, np.ndarray],
    grads: Mapping[str, Mapping[str, np.ndarray]],
    objective_values: Mapping[str, float],
    spp: int,
) -> SelfCheck:
    """Checks (a), (b), (c) on a run's gradients, given its primal image (no render)."""
    linear = {
        o.spec.name: LinearObjective(
            objective_values[o.spec.name], _effective_pixels(loaded, o, image)
        )
        for o in objectives
        if o.spec.type in LINEAR_OBJECTIVES
    }
    emitters = emitter_terms(loaded)
    return check_gradients(loaded.selected, values, grads, linear, emitters, spp, loaded.routes)


def _effective_pixels(loaded: LoadedScene, objective: Objective, image: np.ndarray) -> float:
    """(Σ w)² / Σ w² of the objective's pixel weights: the pixel count a region averages."""
    _, adjoint = value_and_adjoint(loaded.mi, objective, loaded.mi.TensorXf(image))
    weights = np.asarray(adjoint, dtype=np.float64).sum(axis=2)
    return float(weights.sum() ** 2 / max(float((weights**2).sum()), 1e-300))


def emitter_terms(loaded: LoadedScene) -> tuple[EmitterTerms, ...]:
    """Per emitter of the scene, its radiance and scale groups (nodes matched by identity)."""
    params = loaded.params
    by_node: dict[int, list[str]] = {}
    for key in params.keys():
        by_node.setdefault(id(params.properties[key][2]), []).append(key)
    selected = {record.key: record for record in loaded.selected}
    terms = []
    for emitter in loaded.scene.emitters():
        nodes = list(loaded.mi.traverse(emitter).hierarchy)  # alive while ids are compared
        own = by_node.get(id(emitter), [])
        if not own:
            continue
        prefix = own[0].rsplit(".", 1)[0]
        groups: dict[str, list[str] | None] = {"radiance": [], "scale": []}
        for node in nodes:
            for key in by_node.get(id(node), []):
                group = _group(loaded, key[len(prefix) + 1 :].split(".")[0], node, emitter)
                if group is None or not _differentiable(loaded, key):
                    continue
                members = groups[group]
                groups[group] = members + [key] if key in selected and members is not None else None
        first = next((k for g in groups.values() for k in g or () if selected[k].owners), None)
        name = ",".join(selected[first].owners) if first else str(emitter.id())
        terms.append(EmitterTerms(name, *(tuple(g) if g else None for g in groups.values())))
    return tuple(terms)


def _group(loaded: LoadedScene, slot: str, node: Any, emitter: Any) -> str | None:
    """The group ("radiance", "scale" or None) of a parameter in ``slot`` of ``emitter``."""
    if slot in RADIANCE_SLOTS:
        return "radiance"
    if slot == "scale":
        return "scale"
    if slot == "texture":  # a spot light ignores a texture that does not vary over the beam
        top = node
        while loaded.params.hierarchy.get(top, (None,))[0] not in (emitter, None):
            top = loaded.params.hierarchy[top][0]
        return "scale" if top.is_spatially_varying() else None
    return None


def _differentiable(loaded: LoadedScene, key: str) -> bool:
    import drjit as dr

    value, flags = loaded.params[key], loaded.params.properties[key][3]
    non_differentiable = flags & int(loaded.mi.ParamFlags.NonDifferentiable)
    return not non_differentiable and dr.is_diff_v(value) and dr.is_float_v(value)
