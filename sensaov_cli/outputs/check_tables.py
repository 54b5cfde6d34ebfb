"""``sensaov check``'s text tables: reverse mode against finite differences, and duality.

The rows are the render stage's check results, read through the protocols below so that this
stage never imports the renderer.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

from sensaov_cli.outputs.tables import format_table


class GradientRow(Protocol):
    """One row of ``check``'s finite-difference table (the render stage's GradientCheck)."""

    @property
    def key(self) -> str: ...
    @property
    def plugin(self) -> str: ...
    @property
    def type(self) -> str: ...
    @property
    def adjoint(self) -> float: ...
    @property
    def finite_difference(self) -> float: ...
    @property
    def standard_error(self) -> float: ...
    @property
    def verdict(self) -> str: ...
    @property
    def method(self) -> str: ...
    @property
    def claimed_verified(self) -> bool: ...
    @property
    def claimed(self) -> str: ...


class DualityRow(Protocol):
    """One row of ``check``'s duality table (the render stage's DualityCheck)."""

    @property
    def objective(self) -> str: ...
    @property
    def key(self) -> str: ...
    @property
    def direction(self) -> str: ...
    @property
    def trust(self) -> str: ...
    @property
    def reverse(self) -> float: ...
    @property
    def forward(self) -> float: ...
    @property
    def central(self) -> float | None: ...
    @property
    def tolerance(self) -> float: ...
    @property
    def duality_error(self) -> float: ...
    @property
    def central_error(self) -> float | None: ...
    @property
    def central_asked(self) -> bool: ...
    @property
    def verdict(self) -> str: ...


def checks_text(checks: Sequence[GradientRow]) -> str:
    rows = [
        ("key", "plugin", "type", "table", "method", "adjoint", "finite diff", "std err", "verdict")
    ]
    for c in checks:
        rows.append(
            (
                c.key,
                c.plugin,
                c.type,
                c.claimed,  # the table's own label: biased kinds say biased
                c.method,
                f"{c.adjoint:+.3e}",
                f"{c.finite_difference:+.3e}",
                "-" if c.method == "same seed" else f"{c.standard_error:.1e}",
                c.verdict
                + (
                    "  <-- CONTRADICTS THE TABLE"
                    if c.claimed_verified and c.verdict == "disagrees"
                    else ""
                ),
            )
        )
    return "\n".join(format_table(rows))


def duality_text(rows: Sequence[DualityRow], buffer: Path, fd_tolerance: float) -> str:
    """The duality column of ``check``: the buffer against forward mode and central differences."""
    head = (
        f"duality at the buffer's gradient seeds ({buffer}): forward <dM/dI, Jv> vs stored "
        f"<g, v> (tolerance {rows[0].tolerance:.1e} at this size); central differences of "
        f"the image at the same seed (tolerance {fd_tolerance:.0%}; n/a: discontinuous parameter)"
    )
    table = [
        ("objective", "key", "v", "trust", "<g,v>", "forward", "err", "central", "err", "verdict")
    ]
    for d in rows:
        central = "n/a" if d.central is None else f"{d.central:+.4e}"
        central = central if d.central_asked else "(--full)"
        error = "" if d.central_error is None else f"{d.central_error:.1e}"
        table.append(
            (
                d.objective,
                d.key,
                d.direction,
                d.trust,
                f"{d.reverse:+.4e}",
                f"{d.forward:+.4e}",
                f"{d.duality_error:.1e}",
                central,
                error,
                d.verdict,
            )  # fmt: skip
        )
    return "\n".join([head, *format_table(table)])
