"""Display layers: beside every raw sensitivity layer of an EXR, the picture a compositor shows
without a grade.

A raw layer keeps its values untouched (a few 1e-2 at most, often 1e-5: black in any viewer).
Its display layer ``<objective>.<pass>_display.R/G/B`` holds the previews' picture of it: the
signed value at the group's display scale (:mod:`sensaov_cli.views.display_scale`) on the
diverging RdBu map (blue lowers M, red raises it, near-white 0), as linear Rec. 709 values whose
sRGB encoding is exactly the previews' colours, stored as half floats; where the camera hits
nothing it is black. Both layers record the scale, its rule and the share of pixels it clips
(docs/exr-layout.md).
"""

from __future__ import annotations

import json
from collections.abc import Mapping

import numpy as np

from sensaov_cli.outputs.layered_exr import SensitivityLayer
from sensaov_cli.outputs.previews import diverging_linear, diverging_linear_planes
from sensaov_cli.views.display_scale import DisplayScale, clipped_share, signed_pixels

DISPLAY_SUFFIX = "_display"
DISPLAY_ENCODING = (
    "RdBu diverging map of the raw layer at +-display_scale (blue < 0 < red, near-white 0), "
    "linear Rec. 709 (its sRGB encoding is the previews' colours); black where nothing is hit"
)


def display_metadata(scale: DisplayScale, values: np.ndarray) -> dict[str, str]:
    """What a raw layer and its display layer both record about the picture's scale
    (``values``: the layer's signed pixels)."""
    return {
        "display_scale": repr(scale.value),
        "display_rule": scale.rule(),
        "display_scope": scale.scope,
        "display_cameras": json.dumps(list(scale.cameras)),
        # this camera's share of its non-zero pixels
        "display_clipped": repr(clipped_share([values], scale.value)),
        "display_clipped_all": repr(scale.clipped),  # every camera of the rule, weighted equally
    }


def display_background(hit: np.ndarray) -> np.ndarray:
    """(3, H, W) half planes: the display colour of a zero pixel of one camera, whatever the
    layer. Zero is the map's centre at every scale; it fades to black with ``hit``, the
    camera's per-pixel coverage by any object: the float32 colour times the float32 coverage
    clipped to [0, 1], rounded to half once. Computed once per camera, shared by its layers."""
    centre = diverging_linear(np.zeros(1), 1.0)[0]  # (3,) float32, the same at every scale
    fade = np.clip(np.asarray(hit, np.float32), 0.0, 1.0)
    return (centre[:, None, None] * fade[None]).astype(np.float16)


def with_display(
    layer: SensitivityLayer, scale: DisplayScale, background: np.ndarray
) -> tuple[SensitivityLayer, SensitivityLayer]:
    """The raw layer with its display metadata, and its display layer (``background``: the
    camera's :func:`display_background`, shown where the layer is zero)."""
    values = signed_pixels(layer.data, layer.metadata.get("kind", ""))
    shown = display_metadata(scale, values)
    # Stored as half: a picture in [0, 1] needs no more (its sRGB 8-bit codes are the same as
    # float32's, tested), and half the bytes make the EXR write ~40 % faster (issue 23). Drawn
    # as planes, so each EXR channel is contiguous as it is; the layer sees (H, W, 3).
    planes = diverging_linear_planes(values, scale.value, np.float16)
    np.copyto(planes, background, where=(values == 0)[None])
    colours = planes.transpose(1, 2, 0)
    display_name = layer.pass_name + DISPLAY_SUFFIX
    raw = SensitivityLayer(
        layer.objective,
        layer.pass_name,
        layer.data,
        {**layer.metadata, **shown, "display_layer": f"{layer.objective}.{display_name}"},
    )
    keep = ("camera", "buffer", "scale_group", "part", "left_out")
    display = SensitivityLayer(
        layer.objective,
        display_name,
        colours,
        {
            **{k: v for k, v in layer.metadata.items() if k in keep},
            **shown,
            "kind": "display",
            "display_of": layer.original_name,
            "encoding": DISPLAY_ENCODING,
            "original_name": f"{layer.objective}.{display_name}",
        },
    )
    return raw, display


def scale_of(
    scales: Mapping[tuple[str, str], DisplayScale], camera: str, layer: SensitivityLayer
) -> DisplayScale:
    """The display scale of ``layer`` in ``camera`` (its ``scale_group``)."""
    return scales[(camera, layer.metadata["scale_group"])]
