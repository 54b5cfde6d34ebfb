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
from sensaov_cli.outputs.previews import diverging_linear
from sensaov_cli.views.display_scale import DisplayScale, clipped_share, signed_pixels

DISPLAY_SUFFIX = "_display"
DISPLAY_ENCODING = (
    "RdBu diverging map of the raw layer at +-display_scale (blue < 0 < red, near-white 0), "
    "linear Rec. 709 (its sRGB encoding is the previews' colours); black where nothing is hit"
)


def display_metadata(layer: SensitivityLayer, scale: DisplayScale) -> dict[str, str]:
    """What a raw layer and its display layer both record about the picture's scale."""
    here = clipped_share([signed_pixels(layer.data, layer.metadata.get("kind", ""))], scale.value)
    return {
        "display_scale": repr(scale.value),
        "display_rule": scale.rule(),
        "display_scope": scale.scope,
        "display_cameras": json.dumps(list(scale.cameras)),
        "display_clipped": repr(here),  # this camera's share of its non-zero pixels
        "display_clipped_all": repr(scale.clipped),  # every camera of the rule, weighted equally
    }


def with_display(
    layer: SensitivityLayer, scale: DisplayScale, hit: np.ndarray
) -> tuple[SensitivityLayer, SensitivityLayer]:
    """The raw layer with its display metadata, and its display layer (``hit``: the camera's
    per-pixel coverage by any object, in [0, 1])."""
    shown = display_metadata(layer, scale)
    values = signed_pixels(layer.data, layer.metadata.get("kind", ""))
    colours = diverging_linear(values, scale.value)
    # Zero pixels fade to black with the coverage; alpha is 1 elsewhere. float32 products of
    # float32 factors round as the float64 product would (it is exact).
    faded = colours * np.clip(hit, 0.0, 1.0).astype(np.float32)[..., None]
    # Stored as half: a picture in [0, 1] needs no more (its sRGB 8-bit codes are the same as
    # float32's, tested), and half the bytes make the EXR write ~40 % faster (issue 23).
    colours = np.where((values == 0)[..., None], faded, colours).astype(np.float16)
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
