"""Forward passes (§4): the image's derivative J·v along one pushed group of parameters.

One pass per pushed group and seed. Gradients are enabled on the pushed parameters only (a
gradient-enabled parameter elsewhere makes prb's ``render_forward`` raise, MITSUBA-NOTES
"Forward mode"), their tangent set to v, and the image's tangent read back. Parameters prb cannot
differentiate (delta lobes, ``trust.gradient_integrator``) go through Mitsuba's ``path``
integrator in the same chunks and chunk seeds as :mod:`.adjoint`'s backward pass, so that at the
same seed ⟨dM/dI, J·v⟩ equals the buffer's ⟨g, v⟩ (forward/reverse duality, docs/verification.md).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from sensaov_cli import interrupts
from sensaov_cli.render.adjoint import (
    chunk_seed,
    enable_gradients,
    integrator_plan,
    nothing_attached,
    path_chunks,
    path_integrator,
    reproducible,
    subpasses,
)
from sensaov_cli.render.loading import LoadedScene, value_like
from sensaov_cli.render.objectives import Objective, value_and_adjoint


@dataclass(frozen=True)
class ForwardImage:
    """J·v at the objective camera, (H, W, C) float32, or why Mitsuba could not produce it."""

    image: np.ndarray | None
    seconds: float  # wall time of the pass, kernels synchronised
    integrators: tuple[str, ...]  # which integrators pushed which part of the group
    failure: str = ""  # Mitsuba's message when it cannot compute this derivative


def adjoint_images(
    loaded: LoadedScene, objectives: list[Objective], primal: np.ndarray
) -> dict[str, np.ndarray]:
    """dM/dI of each objective at the run's primal image, as the backward passes used it."""
    image = loaded.mi.TensorXf(np.ascontiguousarray(primal, dtype=np.float32))
    result = {}
    for objective in objectives:
        _, adjoint = value_and_adjoint(loaded.mi, objective, image)
        result[objective.spec.name] = np.array(adjoint, dtype=np.float32).reshape(primal.shape)
    return result


def forward_image(
    loaded: LoadedScene,
    direction: dict[str, np.ndarray],
    *,
    spp: int,
    seed: int,
    shape: tuple[int, ...],
    deterministic: bool = True,
) -> ForwardImage:
    """J·v for v = ``direction`` (key -> array in the key's recorded shape), at ``seed``.

    ``shape`` is the primal image's (H, W, C): the shape of J·v when nothing pushed reaches it.
    """
    import drjit as dr

    started = time.perf_counter()
    plan = {
        name: keys & set(direction) for name, keys in integrator_plan(loaded).items()
    }  # fmt: skip
    plan = {name: keys for name, keys in plan.items() if keys}
    total: np.ndarray | None = None
    try:
        with reproducible(loaded, deterministic):
            for name, keys in plan.items():
                part = _push(loaded, name, {k: direction[k] for k in keys}, spp, seed, shape)
                total = part if total is None else total + part
    except Exception as exc:  # Mitsuba raises plain exceptions: the derivative is not available
        enable_gradients(loaded, set())
        message = " ".join(str(exc).split())[:200]
        return ForwardImage(None, time.perf_counter() - started, tuple(plan), message)
    dr.sync_thread()
    if total is None:  # no pushed parameter is differentiable at all
        total = np.zeros(shape, np.float32)
    return ForwardImage(total, time.perf_counter() - started, tuple(plan))


def _push(
    loaded: LoadedScene,
    name: str,
    direction: dict[str, np.ndarray],
    spp: int,
    seed: int,
    shape: tuple[int, ...],
) -> np.ndarray:
    """One integrator's share of J·v; leaves no gradient-enabled parameter behind.

    prb's share is rendered in the backward pass's sub-passes (same seeds, same shares of spp,
    :func:`.adjoint.subpasses`), v pushed afresh for each: duality holds pass by pass.
    """
    if name != "prb":
        _push_leaves(loaded, direction)
        try:
            leaves = loaded.leaves
            tangents = {leaves[k]: value_like(leaves[k], v) for k, v in direction.items()}
            return _path_forward(loaded, tangents, spp, seed, shape)
        finally:
            enable_gradients(loaded, set())
    width, height = loaded.resolution
    total = np.zeros(shape, np.float64)  # summed in float64 over sub-passes, as the backward
    for index, chunk in subpasses(width * height, spp):
        _push_leaves(loaded, direction)
        try:
            part = _prb_forward(loaded, chunk, chunk_seed(seed, index), shape)
        finally:
            enable_gradients(loaded, set())
        total += part if chunk == spp else part * (chunk / spp)
    return total.astype(np.float32)


def _push_leaves(loaded: LoadedScene, direction: dict[str, np.ndarray]) -> None:
    """Fresh leaves with gradients on the pushed keys only, their tangents set to v."""
    import drjit as dr

    enable_gradients(loaded, set(direction))
    leaves = loaded.leaves
    for key, v in direction.items():
        dr.set_grad(leaves[key], value_like(leaves[key], v))
    # ``params.update()`` may derive values from a leaf (a plastic's lobe weights from its
    # reflectance): push v through those edges now, outside prb's isolate_grad scope.
    dr.enqueue(dr.ADMode.Forward, *[leaves[key] for key in direction])
    dr.traverse(dr.ADMode.Forward, dr.ADFlag.ClearEdges)


def _prb_forward(loaded: LoadedScene, spp: int, seed: int, shape: tuple[int, ...]) -> np.ndarray:
    try:
        tangent = loaded.integrator.render_forward(
            loaded.scene, loaded.params, sensor=loaded.sensor, seed=seed, spp=spp
        )
    except Exception as exc:
        if not nothing_attached(exc):
            raise
        return np.zeros(shape, np.float32)
    return np.array(tangent, dtype=np.float32).reshape(shape)


def _path_forward(
    loaded: LoadedScene, tangents: dict[Any, Any], spp: int, seed: int, shape: tuple[int, ...]
) -> np.ndarray:
    """Chunk by chunk as ``adjoint._path_backward``, through path's own ``render_forward``.

    (Rendering with the AD graph and calling ``dr.forward_to`` by hand differs from the backward
    pass at some seeds; Mitsuba's own ``render_forward`` matches it to float precision.)
    """
    import drjit as dr

    width, height = loaded.resolution
    path = path_integrator(loaded)
    total = np.zeros(shape, np.float32)
    for index, chunk in enumerate(path_chunks(width * height, spp)):
        if index:
            interrupts.raise_if_stopped()
        for leaf, tangent in tangents.items():
            dr.set_grad(leaf, tangent)  # each chunk pushes v afresh
        try:
            part = path.render_forward(
                loaded.scene, loaded.params, sensor=loaded.sensor,
                seed=chunk_seed(seed, index), spp=chunk,
            )  # fmt: skip
        except Exception as exc:
            if not nothing_attached(exc):
                raise
            continue
        total += np.array(part, dtype=np.float32).reshape(shape) * np.float32(chunk / spp)
    return total
