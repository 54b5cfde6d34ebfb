"""The beauty pass an inspection camera's EXR carries beside its sensitivities.

A short full path trace (no gradients) so a compositor has the picture the sensitivities are
painted over; its alpha is the visibility pass's coverage, so the two line up exactly.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sensaov_cli.render.loading import LoadedScene
from sensaov_cli.views.coverage import VisibilityPass


def render_beauty(
    loaded: LoadedScene, sensor: Any, visibility: VisibilityPass, spp: int, seed: int
) -> np.ndarray | None:
    """A quick RGBA render at the inspection camera (alpha = visibility coverage); gradients off."""
    if spp <= 0:
        return None
    import drjit as dr

    with dr.suspend_grad():
        image = loaded.integrator.render(loaded.scene, sensor, seed=seed, spp=spp)
    rgb = np.array(image, dtype=np.float32)[..., :3]
    if rgb.shape[2] < 3:  # a mono variant renders Y (and A): show it grey
        rgb = np.repeat(rgb[..., :1], 3, axis=2)
    return np.concatenate([rgb, visibility.coverage_hit[..., None]], axis=2)
