"""A texel field painted into one camera: Fig. 4's three panels (object, per texel, joint).

- ``object``: every owner of the texture painted with its object value Σ c over all its
  parameters (the vertical cut of §3): the scale a whole material lives on.
- ``texel``: the pooled texel field read at each sample's hit UV with the texture's own
  filter, wrap and ``to_uv``, averaged with the coverage like every other channel; encoded with
  the channel's sign, tone map and normalisation on its own scale (the texel peak).
- ``joint``: the same field as each texel's share of its object's value, per unit UV area
  (``c·H·W / V_object``): 1 everywhere means the object's whole value spread evenly over the
  texture, so the panel sits on the object panel's scale (the paper's ``normalize: joint``).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, replace

import numpy as np

from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.encoding import Encoding, Scale, choose_scale, encode_image
from sensaov_cli.views.pooling import white_noise_factor
from sensaov_cli.views.texel_fields import TexelField
from sensaov_cli.views.texels import Footprint, footprint

PANELS = ("object", "texel", "joint")
_UNSAFE = re.compile(r"[^A-Za-z0-9_]")


@dataclass(frozen=True)
class TexelPass:
    pass_name: str  # "<channel>_<texture token>_<panel>"
    panel: str
    data: np.ndarray  # (H, W) or (H, W, 3) float32, encoded
    scale: Scale
    metadata: dict[str, str]


def texture_token(key: str) -> str:
    """A texture key as one name token: ``wall.reflectance.data`` -> ``wall_reflectance``."""
    stem = key[: -len(".data")] if key.endswith(".data") else key
    return _UNSAFE.sub("_", stem)


def owners_in(tf: TexelField, visibility: VisibilityPass) -> list[str]:
    """The texture's owners among this view's objects, in the order its footprint uses."""
    return [o for o in tf.record.owners if o in visibility.objects]


def texture_footprint(tf: TexelField, visibility: VisibilityPass) -> Footprint:
    """How ``visibility``'s camera sees ``tf``'s texture (shared by objectives and panels)."""
    if visibility.sample_uv is None or visibility.sample_object is None:
        raise ValueError("texel passes need a visibility pass traced with UVs")
    owners = np.array([visibility.objects.index(o) for o in owners_in(tf, visibility)], np.int64)
    return footprint(
        tf.raw.shape[:2], tf.sampling, visibility.sample_uv, visibility.sample_object, owners
    )


def texel_passes(tf: TexelField, visibility: VisibilityPass, seen_by: Footprint) -> list[TexelPass]:
    """The three panels of ``tf`` in this camera, with what each one means in its metadata."""
    names = owners_in(tf, visibility)
    is_owner = np.array([1.0 if o in names else 0.0 for o in visibility.objects])
    seen = seen_by.seen(tf.raw.shape[:2])
    notes = list(tf.notes)
    if not seen.any():
        notes.append("no sample of this camera sees this texture (painted 0)")
    common = _common_metadata(tf, seen, notes)
    return [
        _object_panel(tf, visibility, is_owner, common),
        _texel_panel(tf, seen_by, common),
        _joint_panel(tf, seen_by, names, common),
    ]


def _common_metadata(tf: TexelField, seen: np.ndarray, notes: list[str]) -> dict[str, str]:
    return {
        "texture": tf.record.key,
        "texture_type": tf.record.type,
        "texture_size": f"{tf.raw.shape[1]}x{tf.raw.shape[0]}x{tf.raw.shape[2]}",
        "owners": ", ".join(tf.record.owners),
        "lookup": tf.sampling.describe(),
        "pool": tf.pool.describe(),
        # Seed-to-seed noise σ is divided by this for independent texel noise; measured on
        # the demo scene (correlated noise): 0.39 at 64 spp, 0.35 at 4 spp (docs/texels.md).
        "pool_white_noise_factor": repr(white_noise_factor(tf.pool)),
        "units": tf.channel.units,
        # Pooled / unpooled standard error (median over texels), from the buffer's batches;
        # "none" for a buffer without statistics (render.batches: 1, no shards).
        "stderr_reduction": "none" if tf.stderr_reduction is None else repr(tf.stderr_reduction),
        "signed_sum": repr(tf.signed_sum),
        "pooled_sum": repr(tf.pooled_sum),
        "texels_seen": str(int(seen.sum())),
        "seen_empty_before_pool": str(int(np.count_nonzero(tf.raw_empty & seen))),
        "seen_empty_after_pool": str(int(np.count_nonzero(tf.pooled_empty & seen))),
        "unverified": json.dumps(
            [tf.record.key] if tf.record.trust not in ("verified", "no_gradient") else []
        ),
        "estimators": json.dumps({tf.record.key: tf.record.estimator}),
        "notes": " | ".join(notes),
    }


def _as_layer_data(painted: np.ndarray) -> np.ndarray:
    """(H, W, C) painted field as what a layer stores: Y for one channel, RGB for three."""
    if painted.shape[2] == 3:
        return painted
    return painted.sum(axis=2) if painted.shape[2] != 1 else painted[..., 0]


def _object_panel(
    tf: TexelField, visibility: VisibilityPass, is_owner: np.ndarray, common: dict[str, str]
) -> TexelPass:
    values = np.array([tf.object_values.get(name, 0.0) for name in visibility.objects])
    painted = visibility.paint(values * is_owner)
    peak = max((abs(v) for v in tf.object_values.values()), default=0.0)
    meta = {
        **common,
        "panel": "object",
        "meaning": "Σ θ·∂M/∂θ over all parameters of each owner (weight as the channel)",
        "encoding": "linear;signed",
        "scale": Scale(0.0, 1.0).describe(),
        "panel_scale": repr(peak),
    }
    return TexelPass(_name(tf, "object"), "object", painted, Scale(0.0, 1.0), meta)


def _texel_panel(tf: TexelField, seen_by: Footprint, common: dict[str, str]) -> TexelPass:
    encoding = replace(Encoding.from_channel(tf.channel), aggregate="sum")
    field = np.abs(tf.pooled) if encoding.sign == "magnitude" else tf.pooled
    painted = seen_by.paint(field, np.ones(max(len(tf.record.owners), 1)))
    peak = float(np.abs(field).max()) if field.size else 0.0
    scale = choose_scale(encoding, {"texel_peak": peak}, painted)
    data = encode_image(_as_layer_data(painted), encoding, scale.threshold, scale.scale)
    unit = "per unit UV area" if tf.channel.units == "uv_area" else "per texel"
    meta = {
        **common,
        "panel": "texel",
        "meaning": f"pooled θ·∂M/∂θ {unit} read at each hit UV (weight as the channel)",
        "encoding": encoding.describe(),
        "scale": scale.describe(),
        "panel_scale": repr(peak),
    }
    return TexelPass(_name(tf, "texel"), "texel", data, scale, meta)


def _joint_panel(
    tf: TexelField, seen_by: Footprint, names: list[str], common: dict[str, str]
) -> TexelPass:
    # A texel's share sums its components (scaling the whole texel), so the panel is one Y.
    share = tf.pooled.sum(axis=2, keepdims=True) / tf.unit_factor / tf.texel_area
    inverse = [1.0 / tf.object_values[n] if tf.object_values[n] else 0.0 for n in names]
    painted = seen_by.paint(share, np.array(inverse))
    zero = [name for name, value in tf.object_values.items() if not value]
    meta = {
        **common,
        "panel": "joint",
        "meaning": "each texel's share of its object's value per unit UV area: Σ_rgb c·H·W / V",
        "encoding": "linear;signed;normalize=joint",
        "scale": Scale(0.0, 1.0).describe(),
        "panel_scale": "1.0 (the object's whole value spread evenly over the texture)",
    }
    if zero:
        meta["notes"] = " | ".join(
            filter(None, [meta["notes"], f"object value 0 for {', '.join(zero)}: painted 0"])
        )
    data = _as_layer_data(painted)
    return TexelPass(_name(tf, "joint"), "joint", data, Scale(0.0, 1.0), meta)


def _name(tf: TexelField, panel: str) -> str:
    return f"{tf.channel.name}_{texture_token(tf.record.key)}_{panel}"
