"""Wire ``sensaov sunburst``: a stored buffer -> the hierarchy as rings (SVG or PNG)."""

from __future__ import annotations

from pathlib import Path

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.outputs.atomic import (
    check_writable,
    made_by,
    recorded_inputs,
    refuse_unsafe_outputs,
)
from sensaov_cli.outputs.sunburst_drawing import write_sunburst
from sensaov_cli.views.hierarchy import panels
from sensaov_cli.vocabulary import Aggregate, Order, Untrusted, Weight


def draw_sunburst(
    buffer: Path,
    output: Path,
    *,
    objectives: tuple[str, ...],
    order: Order,
    method: Aggregate,
    weight: Weight,
    untrusted: Untrusted = "apart",
) -> None:
    """Write one disc per objective (or per named objective) to ``output``."""
    loaded = read_buffer(buffer)
    check_writable(output.parent, [output.name])
    refuse_unsafe_outputs(
        [buffer, *recorded_inputs(loaded.provenance)],
        [output],
        where=str(output),
        hint="name another file with -o, e.g. sunburst.svg",
    )
    drawn = panels(
        loaded, objectives or None, order=order, method=method, weight=weight, untrusted=untrusted
    )
    contribution = "θ·∂M/∂θ" if weight == "value" else "∂M/∂θ"
    provenance = {
        **made_by("sunburst"),
        "buffer": str(buffer),
        "order": order,
        "aggregate": method,
        "weight": weight,
        "untrusted": untrusted,
        "buffer_provenance": loaded.provenance,
    }
    write_sunburst(
        output, drawn, order=order, encoding=f"{method} of {contribution}", provenance=provenance
    )
