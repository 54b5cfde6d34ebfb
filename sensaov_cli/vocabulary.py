"""The words a job, a query, an encoding and a buffer share, each list defined once.

The spec validates against these ``Literal`` types (and the JSON Schema lists them), the
queries and the encoding check their arguments against the tuples, and the CLI offers the
tuples as choices: adding a word here adds it everywhere. Standard library only.
"""

from __future__ import annotations

from typing import Literal, get_args

Weight = Literal["value", "raw"]  # θ·∂M/∂θ (a proportional change) | ∂M/∂θ
Sign = Literal["signed", "magnitude"]
Aggregate = Literal["l2", "rms", "sum"]
# The one default score of rankings and pictures: the total response Σ θ·∂M/∂θ of a group (the
# paper's §3 allows it or the per-component ℓ2). Resolution is a property of the signed sum, so
# with this default what is ranked, what is painted and what is tested against noise are one
# number (docs/rankings.md, "One score").
DEFAULT_AGGREGATE: Aggregate = "sum"
Tonemap = Literal["none", "log", "symlog"]
Normalize = Literal["none", "channel", "shared"]
Grouping = Literal["param", "object", "type"]
Cut = Literal["key", "object", "type"]  # what `rank --by` names a grouping (key = param)
Order = Literal["object,type", "type,object"]  # the sunburst's rings, innermost first
Untrusted = Literal["apart", "include"]  # headline views (docs/encoding.md, "Trusted numbers")
ScaleScope = Literal["shared", "tile"]  # display scales (docs/encoding.md, "Display scales")
# The job's own words: job/spec.py describes each.
Variant = Literal[
    "auto",
    "llvm_ad_rgb",
    "cuda_ad_rgb",
    "llvm_ad_mono",
    "cuda_ad_mono",
    "llvm_ad_spectral",
    "cuda_ad_spectral",
]
ObjectiveType = Literal["mean_luminance", "region_luminance", "l2_to_target", "python"]
ChannelKind = Literal["object", "type", "select", "transport", "texel"]
Direction = Literal["value", "ones"]  # θ-weighted (a proportional change) | one per component
PoolKind = Literal["gaussian", "box", "mip", "none"]
TexelUnits = Literal["texel", "uv_area"]
# How far a stored gradient can be trusted (docs/verification.md): checked against finite
# differences | not checked | known to be wrong | identically 0 (never ranked) | failed a
# run-time self-check.
Trust = Literal["verified", "unverified", "biased", "no_gradient", "suspect"]
# Which estimator produced a stored gradient (docs/verification.md, "Repairs"): the scene's prb
# backward pass | Mitsuba's path backward pass (smooth lobes) | central differences with common
# random numbers, where both are known wrong | a merge of shards that did not all agree.
Estimator = Literal["reverse", "reverse-path", "finite-difference", "mixed"]

WEIGHTS: tuple[str, ...] = get_args(Weight)
SIGNS: tuple[str, ...] = get_args(Sign)
AGGREGATES: tuple[str, ...] = get_args(Aggregate)
TONEMAPS: tuple[str, ...] = get_args(Tonemap)
NORMALIZES: tuple[str, ...] = get_args(Normalize)
GROUPINGS: tuple[str, ...] = get_args(Grouping)
CUTS: tuple[str, ...] = get_args(Cut)
ORDERS: tuple[str, ...] = get_args(Order)
UNTRUSTED_MODES: tuple[str, ...] = get_args(Untrusted)
TRUSTS: tuple[str, ...] = get_args(Trust)
ESTIMATORS: tuple[str, ...] = get_args(Estimator)
