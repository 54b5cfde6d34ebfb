"""One pass painted into one camera: per-object values through the coverage, then encoded.

The encoded image is what the EXR stores; its encoding scale is camera-independent, so farm tasks
that each render one camera agree. How a picture of it saturates is :mod:`.display_scale`'s
business; here only the objects with a value that this camera does not see are listed (an
environment map, a point light, anything off-frame), so a legend can name them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sensaov_cli.views.channels import ChannelValues
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.encoding import (
    Encoding,
    Scale,
    choose_scale,
    encode_image,
    signed_object_values,
)


@dataclass(frozen=True)
class PaintedPass:
    encoding: Encoding
    scale: Scale  # how ``data`` was encoded (recorded with the layer)
    data: np.ndarray  # (H, W) float32, encoded
    invisible: tuple[str, ...]  # objects with a non-zero value that this camera does not see


def paint_pass(values: ChannelValues, visibility: VisibilityPass) -> PaintedPass:
    encoding = Encoding.from_channel(values.spec)
    names = visibility.objects
    per_object = signed_object_values(
        dict(zip(names, values.magnitudes, strict=True)),
        dict(zip(names, values.signed_sums, strict=True)),
        encoding.sign,
    )
    painted = visibility.paint(np.array([per_object[name] for name in names]))
    scale = choose_scale(encoding, per_object, painted if encoding.normalize == "channel" else None)
    data = encode_image(painted, encoding, scale.threshold, scale.scale)
    seen = set(visibility.visible_objects)
    invisible = tuple(sorted(n for n, value in per_object.items() if value and n not in seen))
    return PaintedPass(encoding, scale, data, invisible)
