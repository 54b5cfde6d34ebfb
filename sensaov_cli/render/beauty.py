"""The beauty pass an inspection camera's EXR carries beside its sensitivities.

A short full path trace (no gradients) so a compositor has the picture the sensitivities are
painted over; its alpha is the visibility pass's coverage, so the two line up exactly. It is
rendered in the primal's sub-passes (:func:`~.adjoint.subpasses`): a stop is acted on within
one of them, not after the whole render.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sensaov_cli.render.adjoint import chunk_seed, subpasses
from sensaov_cli.render.loading import LoadedScene
from sensaov_cli.views.coverage import VisibilityPass


def render_beauty(
    loaded: LoadedScene, sensor: Any, visibility: VisibilityPass, spp: int, seed: int
) -> np.ndarray | None:
    """A quick RGBA render at the inspection camera (alpha = visibility coverage); gradients off."""
    if spp <= 0:
        return None
    import drjit as dr

    size = sensor.film().crop_size()
    image = None
    for index, chunk in subpasses(int(size[0]) * int(size[1]), spp):
        with dr.suspend_grad():
            part = loaded.integrator.render(
                loaded.scene, sensor, seed=chunk_seed(seed, index), spp=chunk
            )
            weighted = part if chunk == spp else part * (chunk / spp)
            image = weighted if image is None else image + weighted
        dr.eval(image)
    rgb = np.array(image, dtype=np.float32)[..., :3]
    if rgb.shape[2] < 3:  # a mono variant renders Y (and A): show it grey
        rgb = np.repeat(rgb[..., :1], 3, axis=2)
    return np.concatenate([rgb, visibility.coverage_hit[..., None]], axis=2)
