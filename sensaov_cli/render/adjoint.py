"""One primal render at the objective camera, then the backward passes of each objective (§2).

prb's ``render_backward`` takes the image-space adjoint dM/dI directly, so each objective costs
one backward propagation and the primal is rendered once, without AD. The gradient seed differs
from the primal seed so that, for objectives that are non-linear in the image, the adjoint's
noise is independent of the primal's (an unbiased product of two estimates).

prb cannot differentiate smooth (delta) BSDF lobes: their parameters take a second backward
pass of Mitsuba's ``path`` integrator (``trust.gradient_integrator``), with gradients enabled
on those parameters only, its samples split into chunks that bound its memory. After the
passes, :mod:`~sensaov_cli.render.selfcheck` labels what the gradients themselves show to be
wrong (docs/verification.md).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import ParamRecord
from sensaov_cli.progress import Progress
from sensaov_cli.render.objectives import Objective, value_and_adjoint
from sensaov_cli.render.scene import LoadedScene
from sensaov_cli.render.selfcheck import self_check
from sensaov_cli.render.trust import gradient_integrator

SEED_STRIDE = 0x9E3779B1  # golden-ratio stride: distinct, reproducible seeds per objective
# Mitsuba's path integrator differentiates by recording the whole render in the AD graph:
# 3 GB for 128x128 at 256 spp in one pass (measured, docs/verification.md). Passes of at most
# this many samples (pixels x spp) keep it near 200 MB, for 24 % more time.
PATH_SAMPLES_PER_PASS = 1 << 18


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
    params: tuple[ParamRecord, ...] = ()  # the selected records, trust labels after self-checks
    provenance: dict[str, Any] = field(default_factory=dict)  # integrators, self-check figures


def to_numpy(value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """A float32 copy (Dr.Jit may hand out a writable zero-copy view) in the recorded shape."""
    return np.array(value, dtype=np.float32, copy=True).reshape(shape)


def enable_gradients(loaded: LoadedScene, keys: set[str] | None = None) -> dict[str, Any]:
    """Give every selected parameter a fresh leaf of its own; gradients on ``keys`` (default all).

    The gradient is read from our leaf, never from ``params[key]``: an envmap's update replaces
    the tensor that ``params[key]`` refers to by a copy with its halo columns filled in, and the
    gradient of that copy reads 0 (Mitsuba 3.9.1, docs/verification.md). The other parameters
    hold the leaf itself. Leaves not in ``keys`` are detached, so a pass differentiates nothing
    else (prb raises if only delta-lobe parameters carry gradients; path's memory grows with them).
    """
    import drjit as dr

    leaves = {}
    for info in loaded.selected:
        current = loaded.params[info.key]
        leaf = type(current)(dr.detach(current))
        if keys is None or info.key in keys:
            dr.enable_grad(leaf)
        loaded.params[info.key] = leaf
        leaves[info.key] = leaf
    loaded.params.update()  # bitmap and envmap data only take the new tensor after update()
    return leaves


def render_primal(loaded: LoadedScene, spp: int, seed: int, integrator: Any = None) -> Any:
    """The image at ``seed`` through ``integrator`` (default: the scene's prb), without AD."""
    import drjit as dr

    integrator = loaded.integrator if integrator is None else integrator
    with dr.suspend_grad():
        image = integrator.render(loaded.scene, loaded.sensor, seed=seed, spp=spp)
    dr.eval(image)
    dr.sync_thread()  # kernels run asynchronously: without this the primal's timing is fiction
    return image


def integrator_plan(loaded: LoadedScene) -> dict[str, set[str]]:
    """Integrator name -> the selected keys it differentiates (prb first); empty ones left out."""
    plan: dict[str, set[str]] = {"prb": set(), "path": set()}
    for info in loaded.selected:
        plan[gradient_integrator(info.plugin)].add(info.key)
    return {name: keys for name, keys in plan.items() if keys}


def backward(loaded: LoadedScene, adjoint_image: Any, spp: int, seed: int) -> dict[str, np.ndarray]:
    """dM/dθ for every selected parameter, given dM/dI at the objective camera."""
    grads: dict[str, np.ndarray] = {}
    for name, keys in integrator_plan(loaded).items():
        grads.update(backward_pass(loaded, name, keys, adjoint_image, spp, seed))
    return {info.key: grads[info.key] for info in loaded.selected}


def backward_pass(
    loaded: LoadedScene, name: str, keys: set[str], adjoint_image: Any, spp: int, seed: int
) -> dict[str, np.ndarray]:
    """dM/dθ for ``keys`` through integrator ``name`` ("prb": the scene's, or "path")."""
    import drjit as dr

    leaves = enable_gradients(loaded, keys)
    if name == "prb":
        _prb_backward(loaded, adjoint_image, spp, seed)
    else:
        _path_backward(loaded, adjoint_image, spp, seed)
    shapes = {info.key: info.shape for info in loaded.selected}
    grads = {key: to_numpy(dr.grad(leaves[key]), shapes[key]) for key in keys}
    enable_gradients(loaded, set())  # leave no gradient-enabled leaf behind for the next pass
    return grads


# What prb and path raise when no gradient-enabled parameter reaches the image (a spot light's
# unused texture, a parameter Mitsuba does not differentiate): no gradient flows, which is a
# finding for the self-checks (zeros), not an error.
_NOTHING_ATTACHED = ("not attached to the AD graph", "does not depend on the input variable")


@contextmanager
def _nothing_attached_is_zero() -> Iterator[None]:
    try:
        yield
    except Exception as exc:  # Mitsuba raises plain exceptions; anything else propagates
        if not any(message in str(exc) for message in _NOTHING_ATTACHED):
            raise


def _prb_backward(loaded: LoadedScene, adjoint_image: Any, spp: int, seed: int) -> None:
    with _nothing_attached_is_zero():
        loaded.integrator.render_backward(
            loaded.scene, loaded.params, grad_in=adjoint_image, sensor=loaded.sensor,
            seed=seed, spp=spp,
        )  # fmt: skip


def path_chunks(pixels: int, spp: int) -> list[int]:
    """spp split into passes of at most PATH_SAMPLES_PER_PASS samples (at least 1 spp each)."""
    per_pass = max(1, PATH_SAMPLES_PER_PASS // max(pixels, 1))
    count = -(-spp // per_pass)
    return [spp // count + (1 if i < spp % count else 0) for i in range(count)]


def path_integrator(loaded: LoadedScene) -> Any:
    """Mitsuba's ``path`` (``volpath`` beside ``prbvolpath``) with the depth, Russian roulette
    and emitter visibility of the scene's replay integrator, so both see the same image."""
    max_depth = int(getattr(loaded.integrator, "max_depth", 6))
    volumetric = type(loaded.integrator).__name__ == "PRBVolpathIntegrator"
    return loaded.mi.load_dict(
        {
            "type": "volpath" if volumetric else "path",
            "max_depth": -1 if max_depth >= 0xFFFFFFFF else max_depth,  # prb's "infinite"
            "rr_depth": int(getattr(loaded.integrator, "rr_depth", 5)),
            "hide_emitters": bool(getattr(loaded.integrator, "hide_emitters", False)),
        }
    )


def chunk_seed(seed: int, index: int) -> int:
    """The seed of path's ``index``-th chunk; the first is ``seed``, as a primal at ``seed``."""
    return (seed + SEED_STRIDE * index) % 2**31


def _path_backward(loaded: LoadedScene, adjoint_image: Any, spp: int, seed: int) -> None:
    """Accumulate path's gradients chunk by chunk; each chunk's share is its fraction of spp."""
    width, height = loaded.resolution
    path = path_integrator(loaded)
    for index, chunk in enumerate(path_chunks(width * height, spp)):
        with _nothing_attached_is_zero():
            path.render_backward(
                loaded.scene, loaded.params, grad_in=adjoint_image * (chunk / spp),
                sensor=loaded.sensor, seed=chunk_seed(seed, index), spp=chunk,
            )  # fmt: skip


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
    plan = integrator_plan(loaded)
    integrators = {key: name for name, keys in plan.items() for key in keys}
    checked = self_check(
        loaded, objectives, result.image, result.values, result.grads,
        result.objective_values, spp, integrators,
    )  # fmt: skip
    return replace(
        result,
        deterministic=exact,
        params=checked.params,
        provenance={
            "gradient_integrators": {name: sorted(keys) for name, keys in plan.items()},
            "self_checks": checked.figures,
        },
    )


def _run_passes(
    loaded: LoadedScene, objectives: list[Objective], *, spp: int, seed: int, progress: Progress
) -> AdjointResult:
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
        grads[name] = {}
        for integrator, keys in integrator_plan(loaded).items():
            stage = f"backward_{name}_s" if integrator == "prb" else f"backward_{name}_path_s"
            label = f"{integrator} backward pass for '{name}' ({len(keys)} parameters)"
            with progress.stage(stage, label):
                grads[name].update(
                    backward_pass(loaded, integrator, keys, adjoint_image, spp, grad_seeds[name])
                )
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
    loaded.params[key] = replacement
    loaded.params.update()
