"""One primal render at the objective camera, then the backward passes of each objective (§2);
forward passes (§4) along a pushed group of parameters.

prb's ``render_backward`` takes the image-space adjoint dM/dI directly: one backward pass per
objective, one primal without AD. The gradient seed differs from the primal seed so that, for
objectives non-linear in the image, the adjoint's noise is independent of the primal's.

prb cannot differentiate smooth (delta) BSDF lobes: their parameters (``loaded.routes``) take a
second backward pass of Mitsuba's ``path`` integrator, in chunks that bound its memory.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from sensaov_cli import interrupts
from sensaov_cli.buffer.model import ParamRecord, Repair
from sensaov_cli.buffer.shards import batch_plan, derived_seed  # merge checks shards by the plan
from sensaov_cli.buffer.statistics import Statistics, combine_batches, weighted_mean
from sensaov_cli.progress import Progress
from sensaov_cli.render.loading import LoadedScene, value_like
from sensaov_cli.render.objectives import Objective, value_and_adjoint
from sensaov_cli.render.verify.selfcheck import SelfCheck, self_check

SEED_STRIDE = 0x9E3779B1  # golden-ratio stride: distinct, reproducible seeds per objective
# path records the whole render in the AD graph: passes of at most this many samples (pixels x
# spp) bound its memory.
PATH_SAMPLES_PER_PASS = 1 << 18
# A stop (SIGTERM, Ctrl-C) is only acted on between kernel launches: primal and prb passes run
# in sub-passes of at most this many samples, with a check between them; small parameters'
# gradients are summed over sub-passes in float64 (Dr.Jit's float32 atomics sum within one).
SAMPLES_PER_SUBPASS = 1 << 19
SMALL = 4096  # components up to which a gradient is summed over sub-passes in float64


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
    spp: int = 0  # samples per pixel behind the mean (the sum over batches)
    statistics: Statistics | None = None  # standard errors, with >= 2 batches
    repairs: dict[str, Repair] = field(default_factory=dict)  # render/verify/repair.py's records
    checks: SelfCheck | None = None  # what the self-checks found (None: one batch, not checked)
    # per batch, in order: each objective's gradient seed (forward passes replay them)
    batch_grad_seeds: tuple[dict[str, int], ...] = ()


def to_numpy(value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """A float32 copy (Dr.Jit may hand out a writable zero-copy view) in the recorded shape."""
    return np.array(value, dtype=np.float32, copy=True).reshape(shape)


def render_primal(
    loaded: LoadedScene, spp: int, seed: int, integrator: Any = None, sensor: Any = None
) -> Any:
    """The image at ``seed`` through ``integrator`` (default: the scene's prb) at ``sensor``
    (default: the objective camera), without AD, in sub-passes weighted by their share of spp
    (one sub-pass is exactly the single render at ``seed``)."""
    import drjit as dr

    integrator = loaded.integrator if integrator is None else integrator
    sensor = loaded.sensor if sensor is None else sensor
    size = sensor.film().crop_size()
    image = None
    for index, chunk in subpasses(int(size[0]) * int(size[1]), spp):
        with dr.suspend_grad():
            part = integrator.render(loaded.scene, sensor, seed=chunk_seed(seed, index), spp=chunk)
            weighted = part if chunk == spp else part * (chunk / spp)
            image = weighted if image is None else image + weighted
        dr.eval(image)
        dr.sync_thread()  # kernels run asynchronously: without this the timing is fiction
    return image


def subpasses(pixels: int, spp: int, limit: int | None = None) -> Iterator[tuple[int, int]]:
    """(index, spp) of each sub-pass of at most ``limit`` samples (default SAMPLES_PER_SUBPASS,
    read at call time); a pending stop is raised before every sub-pass after the first."""
    for index, chunk in enumerate(sample_chunks(pixels, spp, limit or SAMPLES_PER_SUBPASS)):
        if index:
            interrupts.raise_if_stopped()
        yield index, chunk


def integrator_plan(loaded: LoadedScene) -> dict[str, set[str]]:
    """Integrator name -> the selected keys it differentiates (prb first); empty ones left out."""
    plan: dict[str, set[str]] = {"prb": set(), "path": set()}
    for info in loaded.selected:
        plan[loaded.routes[info.key]].add(info.key)
    return {name: keys for name, keys in plan.items() if keys}


def backward(loaded: LoadedScene, adjoint_image: Any, spp: int, seed: int) -> dict[str, np.ndarray]:
    grads: dict[str, np.ndarray] = {}
    for name, keys in integrator_plan(loaded).items():
        grads.update(backward_pass(loaded, name, keys, adjoint_image, spp, seed))
    return {info.key: grads[info.key] for info in loaded.selected}


def backward_pass(
    loaded: LoadedScene, name: str, keys: set[str], adjoint_image: Any, spp: int, seed: int
) -> dict[str, np.ndarray]:
    """dM/dθ for ``keys`` through integrator ``name`` ("prb": the scene's, or "path")."""
    import drjit as dr

    pass_leaves(loaded, keys)
    shapes = {info.key: info.shape for info in loaded.selected}
    if name == "prb":
        sums = _prb_backward(loaded, adjoint_image, spp, seed, keys)
        return {key: sums[key].astype(np.float32).reshape(shapes[key]) for key in keys}
    # path's gradients accumulate chunk by chunk; each chunk's share is its fraction of spp
    width, height = loaded.resolution
    path = path_integrator(loaded)
    for index, chunk in subpasses(width * height, spp, PATH_SAMPLES_PER_PASS):
        with nothing_attached_is_zero():
            path.render_backward(
                loaded.scene, loaded.params, grad_in=adjoint_image * (chunk / spp),
                sensor=loaded.sensor, seed=chunk_seed(seed, index), spp=chunk,
            )  # fmt: skip
    return {key: to_numpy(dr.grad(loaded.leaves[key]), shapes[key]) for key in keys}


def enable_gradients(loaded: LoadedScene, keys: set[str] | None = None) -> None:
    """Give every selected parameter a fresh leaf of its own (``loaded.leaves``); gradients on
    ``keys`` (default all), the others detached.

    The gradient is read from our leaf, never from ``params[key]``: an envmap's update replaces
    the tensor ``params[key]`` refers to by a copy whose gradient reads 0 (Mitsuba 3.9.1).
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
    loaded.leaves = leaves
    loaded.held_keys = None  # fresh leaves: none a pass may reuse (see pass_leaves)
    loaded.params.update()  # bitmap and envmap data only take the new tensor after update()


def pass_leaves(loaded: LoadedScene, keys: set[str]) -> None:
    """Leaves for a backward pass over ``keys`` in ``loaded.leaves``, their gradients zero:
    the previous pass's when it had the same keys, which skips ``params.update()`` (it re-derives
    a rough plastic's tables, a bitmap's texture: as costly as a small pass)."""
    import drjit as dr

    wanted = frozenset(keys)
    if loaded.held_keys == wanted:
        for key in wanted:
            dr.clear_grad(loaded.leaves[key])
        return
    enable_gradients(loaded, keys)
    loaded.held_keys = wanted


# What prb and path raise when no gradient-enabled parameter reaches the image: no gradient
# flows, a finding for the self-checks (zeros), not an error; in forward mode J·v is 0.
_NOTHING_ATTACHED = ("not attached to the AD graph", "does not depend on the input variable")


@contextmanager
def nothing_attached_is_zero() -> Iterator[None]:
    try:
        yield
    except Exception as exc:  # Mitsuba raises plain exceptions; anything else propagates
        if not any(message in str(exc) for message in _NOTHING_ATTACHED):
            raise


def _prb_backward(
    loaded: LoadedScene, adjoint_image: Any, spp: int, seed: int, keys: set[str]
) -> dict[str, np.ndarray]:
    """prb's backward pass over the leaves of ``keys`` in the primal's sub-passes (same seeds,
    same shares of spp)."""
    import drjit as dr

    width, height = loaded.resolution
    leaves = {key: loaded.leaves[key] for key in keys}
    sums = {key: np.zeros(0) for key in leaves}
    chunks = sample_chunks(width * height, spp, SAMPLES_PER_SUBPASS)
    for index, chunk in subpasses(width * height, spp):
        grad_in = adjoint_image if chunk == spp else adjoint_image * (chunk / spp)
        with nothing_attached_is_zero():
            loaded.integrator.render_backward(
                loaded.scene, loaded.params, grad_in=grad_in, sensor=loaded.sensor,
                seed=chunk_seed(seed, index), spp=chunk,
            )  # fmt: skip
        last = index + 1 == len(chunks)
        # Small parameters gather every sample into a few float32 sums: read and added in
        # float64 after each sub-pass. A texture's texels gather few samples each: read once.
        small = {k: leaf for k, leaf in leaves.items() if last or dr.width(leaf) <= SMALL}
        grads = [dr.grad(leaf) for leaf in small.values()]
        dr.eval(*grads)  # one launch for all of them
        for key, grad in zip(small, grads, strict=True):
            part = np.array(grad, dtype=np.float32).astype(np.float64).ravel()  # zero-copy read
            sums[key] = part if sums[key].size == 0 else sums[key] + part
        if not last:
            for leaf in small.values():
                dr.clear_grad(leaf)
    return sums


def sample_chunks(pixels: int, spp: int, limit: int) -> list[int]:
    """spp split into near-equal passes of at most ``limit`` samples (at least 1 spp each)."""
    per_pass = max(1, limit // max(pixels, 1))
    count = -(-spp // per_pass)
    return [spp // count + (1 if i < spp % count else 0) for i in range(count)]


def path_integrator(loaded: LoadedScene) -> Any:
    """Mitsuba's ``path`` (``volpath`` beside ``prbvolpath``) with the depth, Russian roulette
    and emitter visibility of the scene's replay integrator, so both see the same image."""
    max_depth = int(getattr(loaded.integrator, "max_depth", 6))
    return loaded.mi.load_dict(
        {
            "type": "volpath" if loaded.integrator_type == "prbvolpath" else "path",
            "max_depth": -1 if max_depth >= 0xFFFFFFFF else max_depth,  # prb's "infinite"
            "rr_depth": int(getattr(loaded.integrator, "rr_depth", 5)),
            "hide_emitters": bool(getattr(loaded.integrator, "hide_emitters", False)),
        }
    )


def chunk_seed(seed: int, index: int) -> int:
    """The seed of a pass's ``index``-th chunk; the first is ``seed``. Later ones are hashed: a
    stride would give chunk j of a primal the seed of objective j's backward pass (SEED_STRIDE)."""
    return seed if index == 0 else derived_seed(seed, "chunk", index)


def image_like_backward(loaded: LoadedScene, route: str, spp: int, seed: int) -> Any:
    """The image a backward pass through ``route`` ("prb" or "path") at ``seed`` replays: the
    primal, or path's chunks, each its share of spp (as :func:`backward_pass`)."""
    if route == "prb":
        return render_primal(loaded, spp, seed)
    path = path_integrator(loaded)
    width, height = loaded.resolution
    chunks = sample_chunks(width * height, spp, PATH_SAMPLES_PER_PASS)
    return sum(
        render_primal(loaded, chunk, chunk_seed(seed, index), path) * (chunk / spp)
        for index, chunk in enumerate(chunks)
    )


@contextmanager
def reproducible(loaded: LoadedScene, enabled: bool) -> Iterator[bool]:
    """Run the block on one CPU thread when ``enabled``; yields whether results are bit-exact
    (atomic adds' order, and so their rounding, varies between threads; CUDA has no switch)."""
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


def gradient_seed(primal_seed: int, objective_index: int) -> int:
    """The seed of an objective's backward passes in the batch whose primal has ``primal_seed``."""
    return (primal_seed + SEED_STRIDE * (objective_index + 1)) % 2**31


def run_adjoint(
    loaded: LoadedScene,
    objectives: list[Objective],
    *,
    spp: int,
    seed: int,
    deterministic: bool,
    progress: Progress,
    batches: int = 1,
) -> AdjointResult:
    """Every batch's primal and backward passes, their mean, its statistics and self-checks."""
    plan = batch_plan(spp, seed, batches)
    results = render_batches(loaded, objectives, plan, deterministic, progress)
    return combine(loaded, objectives, results)


def render_batches(
    loaded: LoadedScene,
    objectives: list[Objective],
    plan: list[tuple[int, int]],
    deterministic: bool,
    progress: Progress,
    numbered: tuple[int, int] | None = None,
) -> list[AdjointResult]:
    """One result per batch of ``plan`` (spp, primal seed), not yet combined. ``numbered``: the
    first batch's number and the count progress shows (default: 1 and the plan's length)."""
    first, count = numbered or (1, len(plan))
    results = []
    with reproducible(loaded, deterministic) as exact:
        for index, (batch_spp, batch_seed) in enumerate(plan):
            batch = (first + index, count)
            result = _run_passes(loaded, objectives, batch_spp, batch_seed, progress, batch)
            results.append(replace(result, deterministic=exact))
    return results


def combine(
    loaded: LoadedScene, objectives: list[Objective], results: list[AdjointResult]
) -> AdjointResult:
    """The batches' spp-weighted mean, its statistics (>= 2 batches) and the self-checks.
    ``results[b].provenance["batch"]`` holds batch b's (spp, seed)."""
    spps = [r.spp for r in results]
    seeds = [int(r.provenance["batch"]["seed"]) for r in results]
    grads, objective_values, statistics = combine_batches(
        [info.key for info in loaded.selected],
        results[0].values,
        [r.grads for r in results],
        [r.objective_values for r in results],
        spps,
        seeds,
        "batches",
    )
    image = (
        results[0].image if len(results) == 1 else weighted_mean([r.image for r in results], spps)
    )
    values = results[0].values
    checked = self_check(loaded, objectives, image, values, grads, objective_values, sum(spps))
    integrators = {name: sorted(keys) for name, keys in integrator_plan(loaded).items()}
    provenance = {
        "gradient_integrators": integrators,
        "self_checks": checked.figures(),
        "batches": [{"spp": n, "seed": s} for n, s in zip(spps, seeds, strict=True)],
    }
    return replace(
        results[0], image=image, grads=grads, objective_values=objective_values,
        statistics=statistics, spp=sum(spps), params=checked.params, checks=checked,
        deterministic=all(r.deterministic for r in results),
        provenance=provenance, batch_grad_seeds=tuple(r.grad_seeds for r in results),
    )  # fmt: skip


def _run_passes(
    loaded: LoadedScene,
    objectives: list[Objective],
    spp: int,
    seed: int,
    progress: Progress,
    batch: tuple[int, int],
) -> AdjointResult:
    """One batch (``batch``: its number and the count): a primal, then each objective's backward
    passes."""
    number, count = batch
    tag, suffix = (f"batch {number}/{count}: ", f"_batch{number}") if count > 1 else ("", "")
    width, height = loaded.resolution
    with progress.stage(f"primal{suffix}_s", f"{tag}primal render {width}x{height} at {spp} spp"):
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
            path = "" if integrator == "prb" else "_path"
            stage = f"backward_{name}{path}{suffix}_s"
            label = f"{tag}{integrator} backward pass for '{name}' ({len(keys)} parameters)"
            with progress.stage(stage, label):
                grads[name].update(
                    backward_pass(loaded, integrator, keys, adjoint_image, spp, grad_seeds[name])
                )
        objective_values[name] = value
    return AdjointResult(
        np.array(image, dtype=np.float32), values, objective_values, grad_seeds, grads, spp=spp,
        provenance={"batch": {"spp": spp, "seed": seed}},
    )  # fmt: skip


# --- what the job's max_depth changes: the replay's image against the scene's own ------------
# Both at one seed (common random numbers: the difference is far less noisy than either).

EFFECT_SPP = 8  # samples per pixel of the two renders: cheap beside a run's own passes


@dataclass(frozen=True)
class ImageEffect:
    objective: str
    value: float  # M on the image the run differentiates
    scene_value: float  # M on the image the scene renders
    spp: int

    @property
    def relative(self) -> float:
        return self.value / self.scene_value - 1.0 if self.scene_value else 0.0


def depth_effect(
    loaded: LoadedScene, objectives: list[Objective], scene_image: dict[str, Any], seed: int
) -> list[ImageEffect]:
    """M of each objective on the replay's image and on the image at the scene's depth
    (``scene_image``: the Mitsuba dict of the scene's own integrator)."""
    scene_integrator = loaded.mi.load_dict(scene_image)
    ours = render_primal(loaded, EFFECT_SPP, seed)
    theirs = render_primal(loaded, EFFECT_SPP, seed, scene_integrator)

    def value(objective: Objective, image: Any) -> float:
        return value_and_adjoint(loaded.mi, objective, image)[0]

    return [
        ImageEffect(o.spec.name, value(o, ours), value(o, theirs), EFFECT_SPP) for o in objectives
    ]


# --- forward passes (§4): the image's derivative J·v along one pushed group of parameters.
# Gradients are enabled on the pushed parameters only (any other makes prb's ``render_forward``
# raise, MITSUBA-NOTES "Forward mode"). Each integrator pushes its share in the chunks and chunk
# seeds of the backward pass, so that at the same seed ⟨dM/dI, J·v⟩ equals the buffer's ⟨g, v⟩
# (forward/reverse duality, docs/verification.md).


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
    """J·v for v = ``direction`` (key -> array in the key's recorded shape), at ``seed``;
    ``shape``: the primal image's (H, W, C)."""
    import drjit as dr

    started = time.perf_counter()
    plan = {name: keys & set(direction) for name, keys in integrator_plan(loaded).items()}
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


def batches_forward_image(
    loaded: LoadedScene,
    direction: dict[str, np.ndarray],
    *,
    batches: Sequence[tuple[int, int]],
    shape: tuple[int, ...],
    deterministic: bool = True,
) -> ForwardImage:
    """J·v as a run with several batches computes its gradient: one pass per batch at that
    batch's (spp, gradient seed), their spp-weighted mean; so ⟨dM/dI, J·v⟩ is the batch mean
    ⟨g, v⟩ (docs/verification.md). One batch is :func:`forward_image` itself."""
    if len(batches) == 1:
        spp, seed = batches[0]
        return forward_image(
            loaded, direction, spp=spp, seed=seed, shape=shape, deterministic=deterministic
        )
    total = float(sum(spp for spp, _ in batches))
    mean = np.zeros(shape, np.float64)
    seconds, integrators = 0.0, tuple[str, ...]()
    for spp, seed in batches:
        part = forward_image(
            loaded, direction, spp=spp, seed=seed, shape=shape, deterministic=deterministic
        )
        seconds += part.seconds
        integrators = integrators or part.integrators
        if part.image is None:
            return replace(part, seconds=seconds)
        mean += part.image.astype(np.float64) * (spp / total)
    return ForwardImage(mean.astype(np.float32), seconds, integrators)


def _push(
    loaded: LoadedScene,
    name: str,
    direction: dict[str, np.ndarray],
    spp: int,
    seed: int,
    shape: tuple[int, ...],
) -> np.ndarray:
    """One integrator's share of J·v, v pushed afresh for each of prb's sub-passes; leaves no
    gradient-enabled parameter behind."""
    if name != "prb":
        _push_leaves(loaded, direction)
        try:
            leaves = loaded.leaves
            tangents = {leaves[k]: value_like(leaves[k], v) for k, v in direction.items()}
            return _path_forward(loaded, tangents, spp, seed, shape)
        finally:
            enable_gradients(loaded, set())
    width, height = loaded.resolution
    total = np.zeros(shape, np.float64)  # summed in float64, as the backward
    for index, chunk in subpasses(width * height, spp):
        _push_leaves(loaded, direction)
        tangent, at = None, chunk_seed(seed, index)
        try:
            with nothing_attached_is_zero():
                tangent = loaded.integrator.render_forward(
                    loaded.scene, loaded.params, sensor=loaded.sensor, seed=at, spp=chunk
                )
        finally:
            enable_gradients(loaded, set())
        if tangent is not None:
            part = np.array(tangent, dtype=np.float32).reshape(shape)
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


def _path_forward(
    loaded: LoadedScene, tangents: dict[Any, Any], spp: int, seed: int, shape: tuple[int, ...]
) -> np.ndarray:
    """Chunk by chunk as :func:`backward_pass`, through path's own ``render_forward``
    (``dr.forward_to`` by hand differs from the backward pass at some seeds)."""
    import drjit as dr

    width, height = loaded.resolution
    path = path_integrator(loaded)
    total = np.zeros(shape, np.float32)
    for index, chunk in subpasses(width * height, spp, PATH_SAMPLES_PER_PASS):
        for leaf, tangent in tangents.items():
            dr.set_grad(leaf, tangent)  # each chunk pushes v afresh
        part = None
        with nothing_attached_is_zero():
            part = path.render_forward(
                loaded.scene, loaded.params, sensor=loaded.sensor,
                seed=chunk_seed(seed, index), spp=chunk,
            )  # fmt: skip
        if part is not None:
            total += np.array(part, dtype=np.float32).reshape(shape) * np.float32(chunk / spp)
    return total
