"""One primal render at the objective camera, then one backward pass per objective (paper §2).

prb's ``render_backward`` takes the image-space adjoint dM/dI directly, so each objective costs
one backward propagation and the primal is rendered once, without AD. The gradient seed differs
from the primal seed so that, for objectives that are non-linear in the image, the adjoint's
noise is independent of the primal's (an unbiased product of two estimates).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from sensaov_cli.progress import Progress
from sensaov_cli.render.objectives import Objective, value_and_adjoint
from sensaov_cli.render.scene import LoadedScene

SEED_STRIDE = 0x9E3779B1  # golden-ratio stride: distinct, reproducible seeds per objective


def gradient_seed(primal_seed: int, objective_index: int) -> int:
    return (primal_seed + SEED_STRIDE * (objective_index + 1)) % 2**31


@dataclass(frozen=True)
class AdjointResult:
    image: np.ndarray  # the primal at the objective camera, (H, W, C) float32
    values: dict[str, np.ndarray]  # parameter key -> value
    objective_values: dict[str, float]
    grad_seeds: dict[str, int]
    grads: dict[str, dict[str, np.ndarray]]  # objective -> key -> dM/dθ
    deterministic: bool = False  # computed so that the same job and seed give the same bits


def to_numpy(value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """A float32 copy (Dr.Jit may hand out a writable zero-copy view) in the recorded shape."""
    return np.array(value, dtype=np.float32, copy=True).reshape(shape)


def enable_gradients(loaded: LoadedScene) -> None:
    import drjit as dr

    for info in loaded.selected:
        dr.enable_grad(loaded.params[info.key])
    loaded.params.update()  # bitmap data only takes the gradient-enabled tensor after update()


def render_primal(loaded: LoadedScene, spp: int, seed: int) -> Any:
    import drjit as dr

    with dr.suspend_grad():
        image = loaded.integrator.render(loaded.scene, loaded.sensor, seed=seed, spp=spp)
    dr.eval(image)
    dr.sync_thread()  # kernels run asynchronously: without this the primal's timing is fiction
    return image


def backward(loaded: LoadedScene, adjoint_image: Any, spp: int, seed: int) -> dict[str, np.ndarray]:
    """dM/dθ for every selected parameter, given dM/dI at the objective camera."""
    import drjit as dr

    for info in loaded.selected:
        dr.clear_grad(loaded.params[info.key])
    loaded.integrator.render_backward(
        loaded.scene, loaded.params, grad_in=adjoint_image, sensor=loaded.sensor, seed=seed, spp=spp
    )
    grads = {
        info.key: to_numpy(dr.grad(loaded.params[info.key]), info.shape) for info in loaded.selected
    }
    for info in loaded.selected:
        dr.clear_grad(loaded.params[info.key])
    return grads


@contextmanager
def reproducible(loaded: LoadedScene, enabled: bool) -> Iterator[bool]:
    """Run the block on one CPU thread when ``enabled``; yields whether results are bit-exact.

    Gradients of parameters are accumulated with atomic adds, whose order (and so the float32
    rounding) varies between threads. One thread fixes the order. CUDA has no such switch.
    """
    import drjit as dr

    if not enabled or not loaded.variant.startswith("llvm"):
        yield False
        return
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        yield True
    finally:
        dr.set_thread_count(threads)


def run_adjoint(
    loaded: LoadedScene,
    objectives: list[Objective],
    *,
    spp: int,
    seed: int,
    deterministic: bool,
    progress: Progress,
) -> AdjointResult:
    with reproducible(loaded, deterministic) as exact:
        result = _run_passes(loaded, objectives, spp=spp, seed=seed, progress=progress)
    return replace(result, deterministic=exact)


def _run_passes(
    loaded: LoadedScene, objectives: list[Objective], *, spp: int, seed: int, progress: Progress
) -> AdjointResult:
    enable_gradients(loaded)
    width, height = loaded.resolution
    with progress.stage("primal_s", f"primal render {width}x{height} at {spp} spp"):
        image = render_primal(loaded, spp, seed)
    values = {info.key: to_numpy(loaded.params[info.key], info.shape) for info in loaded.selected}
    objective_values: dict[str, float] = {}
    grad_seeds: dict[str, int] = {}
    grads: dict[str, dict[str, np.ndarray]] = {}
    for objective in objectives:
        name = objective.spec.name
        value, adjoint_image = value_and_adjoint(loaded.mi, objective, image)
        grad_seeds[name] = gradient_seed(seed, objective.index)
        label = f"backward pass for '{name}' ({len(loaded.selected)} parameters)"
        with progress.stage(f"backward_{name}_s", label):
            grads[name] = backward(loaded, adjoint_image, spp, grad_seeds[name])
        objective_values[name] = value
    return AdjointResult(
        np.array(image, dtype=np.float32), values, objective_values, grad_seeds, grads
    )


def assign(loaded: LoadedScene, key: str, array: np.ndarray) -> None:
    """Set a selected parameter to ``array`` (in its recorded shape), for finite differences."""
    import drjit as dr

    current = loaded.params[key]
    flat = np.ascontiguousarray(array, dtype=np.float32)
    if dr.is_tensor_v(current):
        replacement = type(current)(flat)
    elif dr.size_v(current) == 3:  # a colour: one value per channel
        replacement = type(current)(*[float(v) for v in flat.reshape(-1)])
    else:
        replacement = type(current)(flat.reshape(-1))
    dr.enable_grad(replacement)  # the new value replaces a gradient-enabled leaf
    loaded.params[key] = replacement
    loaded.params.update()


def objective_at_seed(loaded: LoadedScene, objective: Objective, spp: int, seed: int) -> float:
    """M of a fresh primal render at ``seed`` (finite differences hold the seed fixed)."""
    value, _ = value_and_adjoint(loaded.mi, objective, render_primal(loaded, spp, seed))
    return value
