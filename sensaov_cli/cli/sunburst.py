"""``sensaov sunburst``: the buffer's hierarchy as rings, one disc per objective (SVG or PNG)."""

from __future__ import annotations

from pathlib import Path

import click

from sensaov_cli.cli import options
from sensaov_cli.vocabulary import ORDERS, Aggregate, Order, Untrusted, Weight


@options.command
@click.argument("buffer", type=options.FilePath(path_type=Path))
@options.objective_option(
    help="Draw only this objective (repeatable; default: one disc per objective)."
)
@click.option(
    "--order",
    type=click.Choice(ORDERS),
    default="object,type",
    show_default=True,
    help="The rings between the objective and the parameters, innermost first.",
)
@options.aggregate_option
@options.weight_option
@options.untrusted_option
@options.output_option(
    default=Path("sunburst.svg"), show_default=True, help="The file to write: .svg or .png."
)
def sunburst(
    buffer: Path,
    objective: tuple[str, ...],
    order: Order,  # click.Choice gives one of these
    aggregate: Aggregate,
    weight: Weight,
    untrusted: Untrusted,
    output: Path,
) -> None:
    """Draw a sunburst of a stored buffer (numpy and matplotlib, no rendering).

    \b
    Rings from the centre: the objective, then objects, then their parameter
    types, then the parameters (--order type,object swaps the middle rings).
    Siblings share their parent's angle in proportion to their scores; colour
    is the signed sum (blue: raising the group lowers M, red: raises it);
    a gradient sensaov does not stand behind is left out of its object and
    drawn apart, in a hatched "(untrusted)" wedge. docs/rankings.md.

    \b
    Example:
      sensaov sunburst out/cbox/buffer.npz -o out/cbox/sunburst.svg
      sensaov sunburst out/cbox/buffer.npz --objective mean_luma --order type,object -o s.png
    """
    from sensaov_cli.pipeline.sunburst import draw_sunburst

    draw_sunburst(
        buffer, output, objectives=objective, order=order, method=aggregate, weight=weight,
        untrusted=untrusted,
    )  # fmt: skip
    click.echo(str(output))
