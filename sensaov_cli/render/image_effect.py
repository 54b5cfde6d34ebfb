"""What a change of the scene's image does to M: the replay's image against the scene's own.

Where the job's ``render.max_depth`` differs from the depth the scene renders, M is measured on
another image than the user's scene shows. Both are rendered here at a few samples per pixel and
one seed, the replay as it will run and the same integrator at the scene's depth, so that the
warning says by how much (common random numbers: the difference is far less noisy than either
image).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sensaov_cli.render.adjoint import render_primal
from sensaov_cli.render.loading import LoadedScene
from sensaov_cli.render.objectives import Objective, value_and_adjoint

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
    """M of each objective on the replay's image and on the image at the scene's depth."""
    spp = EFFECT_SPP
    scene_integrator = loaded.mi.load_dict(scene_image)
    ours = render_primal(loaded, spp, seed)
    theirs = render_primal(loaded, spp, seed, scene_integrator)
    return [
        ImageEffect(
            objective.spec.name,
            value_and_adjoint(loaded.mi, objective, ours)[0],
            value_and_adjoint(loaded.mi, objective, theirs)[0],
            spp,
        )
        for objective in objectives
    ]
