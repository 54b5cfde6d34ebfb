"""The legend's encoding said in words, for the person reading the page.

The encoding travels as ``weight=value;sign=signed;aggregate=l2;...`` (docs/encoding.md): exact
for files and scripts, opaque to a person. The page shows these words and keeps the exact
string as the words' tooltip.
"""

from __future__ import annotations

from sensaov_cli.errors import SensaovError
from sensaov_cli.live.inspection import Legend
from sensaov_cli.views.channels import Encoding

_WEIGHT = {
    "value": "θ·∂M/∂θ: how M responds to a proportional change of each parameter",
    "raw": "∂M/∂θ: how M responds to a change of each parameter by one of its units",
}
_AGGREGATE = {
    "l2": "combined per object as the root of the sum of squares, with the sign of the plain sum",
    "rms": "combined per object as the root mean square, with the sign of the plain sum",
    "sum": "summed per object",
}
_SIGN = {
    "signed": "red where raising them raises M, blue where it lowers M",
    "magnitude": "size only: the colour does not say which way M moves",
}
_TONEMAP = {
    "none": "colours linear in the value",
    "log": "colours on a log scale, so small values stay visible",
    "symlog": "colours on a log scale either side of 0, so small values stay visible",
}
_FIXED = " (fixed by the job's texel channel)"


def legend_words(legend: Legend) -> str:
    """What ``legend.encoding`` means, in a sentence."""
    text, fixed = legend.encoding, legend.encoding.endswith(_FIXED)
    try:
        encoding = Encoding.parse(text.removesuffix(_FIXED))
    except SensaovError:  # an encoding this module does not know: shown as it is
        return text
    if legend.scale_mode == "image":  # a rendered image: no parameters were weighted or summed
        parts = ["the image's derivative per pixel", _SIGN[encoding.sign]]
    else:
        parts = [_WEIGHT[encoding.weight], _AGGREGATE[encoding.aggregate], _SIGN[encoding.sign]]
    parts.append(_TONEMAP[encoding.tonemap])
    sentence = "; ".join(parts)
    return sentence + (" (as the job's texel channel asks)" if fixed else "")
