"""Check a stored buffer against forward mode: duality and central differences at one seed.

For the top-k parameters of each objective (or named keys) and a few directions v (ones, then
seeded Gaussian ones), three numbers at the buffer's gradient seed of that objective:

- reverse  ⟨g, v⟩ from the buffer's stored gradient;
- forward  ⟨dM/dI, J·v⟩ from ``render_forward`` (same seed, integrator, spp as the backward
  pass): equal to reverse up to float32 rounding, so a larger gap means the stored gradient is
  not the one this job computes (a corrupt or stale buffer) — ``duality_tolerance``;
- central  ⟨dM/dI, (I(θ+εv) − I(θ−εv)) / 2ε⟩, the images rendered at the same seed: checks
  Mitsuba's derivative itself, within FD_TOLERANCE. Parameters flagged discontinuous (their
  value changes which paths are sampled) are not checkable this way: that cell reads "n/a".

A failed duality fails whatever the trust label (both sides come from the same AD); a failed
central difference fails only a parameter the buffer labels verified (docs/verification.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sensaov_cli.buffer.forward_sidecar import DUALITY_FLOOR, duality_tolerance
from sensaov_cli.buffer.model import ParamRecord, SensitivityBuffer
from sensaov_cli.progress import Progress
from sensaov_cli.render.adjoint import image_like_backward, render_primal
from sensaov_cli.render.forward import adjoint_images, forward_image
from sensaov_cli.render.loading import LoadedScene
from sensaov_cli.render.objectives import Objective
from sensaov_cli.render.verify.fdcheck import STEP, difference
from sensaov_cli.vocabulary import Trust

# Same-seed central differences (fdcheck.STEP): 2 % leaves room for a path that crosses a
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
    progress: Progress | None = None,
    central: bool = True,
) -> list[DualityCheck]:
    """One row per (objective, key, direction), each a progress line; ``central``: also the
    central difference of the image (two renders a row)."""
    progress = progress or Progress(quiet=True)
    spp = int(buffer.provenance["spp"])
    primal = np.array(render_primal(loaded, spp, int(buffer.provenance["primal_seed"])))
    adjoints = adjoint_images(loaded, objectives, primal)
    records = {info.key: info for info in loaded.selected}  # ``keys``: checked by fdcheck.named
    tolerance = duality_tolerance(primal.shape[0] * primal.shape[1] * spp)
    rows: list[DualityCheck] = []
    for objective in objectives:
        name = objective.spec.name
        for key in keys or top_keys(buffer, name, top):
            for label, v in directions(records[key], random_directions, seed=len(rows)):
                stage = f"check: duality of {key} along {label} for '{name}'"
                with progress.stage(f"duality_{len(rows)}_s", stage):
                    row = _row(
                        loaded, buffer, name, records[key], label, v, adjoints[name], central
                    )
                    rows.append(row)
    return [replace(row, tolerance=tolerance) for row in rows]


def _row(
    loaded: LoadedScene,
    buffer: SensitivityBuffer,
    objective: str,
    info: ParamRecord,
    label: str,
    v: np.ndarray,
    adjoint: np.ndarray,
    asked: bool,
) -> DualityCheck:
    spp = int(buffer.provenance["spp"])
    seed = buffer.objective(objective).grad_seed
    stored = buffer.reverse_grad(objective, info.key).astype(np.float64)  # forward's dual
    reverse = float(np.dot(stored.ravel(), v.ravel()))
    pushed = forward_image(loaded, {info.key: v}, spp=spp, seed=seed, shape=adjoint.shape)
    forward = _weighted(adjoint, pushed.image) if pushed.image is not None else float("nan")
    central = None
    if asked and "discontinuous" not in info.flags:

        def image_at(side_seed: int) -> np.ndarray:
            image = image_like_backward(loaded, loaded.routes[info.key], spp, side_seed)
            return np.array(image, np.float32).astype(np.float64)

        central = _weighted(adjoint, difference(loaded, info, v, STEP, (seed, seed), image_at))
    record = buffer.param(info.key)
    # A repaired parameter's reverse mode is the one known wrong: its central difference may
    # disagree with forward mode without failing the check.
    trust = "biased" if record.estimator in ("finite-difference", "mixed") else record.trust
    return DualityCheck(
        objective, info.key, label, trust, reverse, forward, central, seed, central_asked=asked
    )


def _weighted(adjoint: np.ndarray, image: np.ndarray) -> float:
    return float((adjoint.astype(np.float64) * image.astype(np.float64)).sum())
