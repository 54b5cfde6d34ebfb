"""The two colour scales ``sensaov view`` offers a channel: the job's shared one, the view's own.

Each is one function so that the rule choosing it can change in one place. Both return the
:class:`~.encoding.Scale` a channel is encoded with (its threshold for the log tone maps and
the tone-mapped value at which colours saturate), and :func:`peak_of` turns that back into the
channel's own units for the legend. The job's shared scale is the number
:func:`~.display_scale.shared_channel_scale` gives, the one ``sensaov project`` records as
``display_scale`` and paints its previews and display layers with (p95 of |v| over the pixels
every inspection camera paints; docs/encoding.md), so the page and the files agree; the view's
own scale applies the same rule to this view's pixels alone.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from sensaov_cli.views.display_scale import DisplayScale, robust_scale
from sensaov_cli.views.encoding import Encoding, Scale, choose_scale


def job_shared_scale(encoding: Encoding, shared: DisplayScale) -> Scale:
    """One scale for the (objective, channel) whatever the camera sees: ``shared``, the job's
    display scale of it (:func:`~.display_scale.shared_channel_scale`), so that every viewpoint
    shows the channel on the colours of ``project``'s previews and display layers (Fig. 6)."""
    return choose_scale(replace(encoding, normalize="shared"), {"shared": shared.value})


def view_own_scale(encoding: Encoding, painted: np.ndarray) -> Scale:
    """This view's own scale: the job's rule (:func:`~.display_scale.robust_scale`) over this
    view's painted pixels alone, so neither an object off frame (an environment light, a lamp
    behind the camera) nor a few bright pixels wash the picture out."""
    own = robust_scale({"view": [painted]}, scope="tile")
    return choose_scale(replace(encoding, normalize="shared"), {"own": own.value})


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
