"""Where Mitsuba's reverse-mode gradient is heavy-tailed, so a repair estimates it better.

A microfacet lobe whose roughness reaches 0 (a roughness texture with texels at 0) is nearly a
delta lobe: prb and path differentiate its η, k and α through ``eval()`` and its sampling
weight, whose derivatives at a near-delta lobe are huge on the rare paths that hit its peak and
small elsewhere. Their per-seed estimates range over thousands of times the derivative, while
central differences with common random numbers, which only see the lobe's effect on the image,
stay as tame as at any roughness (docs/verification.md, "Heavy tails"). Such parameters are
repair candidates (render/verify/repair.py), read from the scene before any render: the
parameters of a rough dielectric or conductor whose roughness (every value of every texture in
its α slots) goes below NEAR_SPECULAR_ROUGHNESS.

The rule reads the scene, not a run's batches: a repair plan must be the same in every farm
shard, and a shard sees only its own batch. Estimates that look heavy-tailed in a buffer
(:func:`~sensaov_cli.buffer.statistics.heavy_tail`) are labelled ``noisy`` by the views instead.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sensaov_cli.render.loading import LoadedScene
from sensaov_cli.render.verify.trust import MITSUBA

MICROFACET_PLUGINS = frozenset({"roughdielectric", "roughconductor"})
# Below this roughness (α) the lobe is treated as a delta one: reverse mode's spread over seeds
# is hundreds of times that of central differences at 0, a few times at 0.01 and 0.02, alike at
# 0.05 (scripts/near_specular_spread.py).
NEAR_SPECULAR_ROUGHNESS = 0.05
_ROUGHNESS_SLOTS = frozenset({"alpha", "alpha_u", "alpha_v"})


def near_specular_reason(roughness: float) -> str:
    return (
        f"near-specular: its roughness goes down to {roughness:.3g} (below "
        f"{NEAR_SPECULAR_ROUGHNESS:g}), where {MITSUBA}'s reverse-mode derivative of the nearly "
        "smooth lobe is heavy-tailed (a few paths carry it)"
    )


def near_specular(loaded: LoadedScene) -> dict[str, str]:
    """key -> why, for selected parameters of a rough dielectric or conductor whose roughness
    reaches below NEAR_SPECULAR_ROUGHNESS somewhere."""
    found: dict[str, str] = {}
    smallest: dict[int, float | None] = {}  # id(BSDF) -> its smallest roughness
    for record in loaded.selected:
        if record.plugin not in MICROFACET_PLUGINS:
            continue
        bsdf = _bsdf_of(loaded, loaded.params.properties[record.key][2])
        if bsdf is None:
            continue
        if id(bsdf) not in smallest:
            smallest[id(bsdf)] = smallest_roughness(loaded.mi, bsdf)
        low = smallest[id(bsdf)]
        if low is not None and low < NEAR_SPECULAR_ROUGHNESS:
            found[record.key] = near_specular_reason(low)
    return found


def smallest_roughness(mi: Any, bsdf: Any) -> float | None:
    """The smallest value in the BSDF's roughness slots (uniform values, checkerboard colours,
    bitmap texels), or None where it exposes none."""
    params = mi.traverse(bsdf)
    values = []
    for key in params.keys():
        parts = key.split(".")
        if parts[0] not in _ROUGHNESS_SLOTS or parts[-1] == "to_uv":
            continue
        try:
            array = np.asarray(params[key], dtype=np.float64).ravel()
        except (TypeError, ValueError):  # not a plain number array (a transform, a string)
            continue
        if array.size:
            values.append(float(array.min()))
    return min(values) if values else None


def _bsdf_of(loaded: LoadedScene, node: Any) -> Any:
    """The BSDF that holds ``node`` (the node itself, or the BSDF above its textures)."""
    mi, hierarchy = loaded.mi, loaded.params.hierarchy
    while node is not None and not isinstance(node, mi.BSDF):
        node = hierarchy.get(node, (None,))[0]
    return node
