"""The two colour scales ``sensaov view`` offers a channel: the job's shared one, the view's own.

Each is one function so that the rule choosing it can change in one place. Both return the
:class:`~.encoding.Scale` a channel is encoded with (its threshold for the log tone maps and
the tone-mapped value at which colours saturate), and :func:`peak_of` turns that back into the
channel's own units for the legend.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.encoding import Encoding, Scale, choose_scale


def job_shared_scale(encoding: Encoding, per_object: Mapping[str, float]) -> Scale:
    """One scale for the (objective, channel) whatever the camera sees: the peak over every
    object's value, so that every viewpoint shows the channel on the same colours (Fig. 6)."""
    return choose_scale(replace(encoding, normalize="shared"), per_object)


def view_own_scale(
    encoding: Encoding, per_object: Mapping[str, float], visibility: VisibilityPass
) -> Scale:
    """This view's own scale: the peak over the objects it sees, so that an object off frame
    (an environment light, a lamp behind the camera) never washes the picture out."""
    seen = set(visibility.visible_objects)
    shown = {name: value for name, value in per_object.items() if name in seen}
    return choose_scale(replace(encoding, normalize="shared"), shown)


def peak_of(scale: Scale, tonemap: str) -> float:
    """The value, in the channel's units, at which colours saturate under ``scale``."""
    if tonemap == "none":
        return scale.scale
    return scale.threshold * (10.0**scale.scale - 1.0)


def value_at(position: float, scale: Scale, tonemap: str) -> float:
    """The channel value drawn at ``position`` in [-1, 1] of the colour bar (its inverse)."""
    t = position * scale.scale
    if tonemap == "none":
        return t
    return math.copysign(scale.threshold * (10.0 ** abs(t) - 1.0), t)
