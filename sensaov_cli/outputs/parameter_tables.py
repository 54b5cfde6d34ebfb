"""What ``sensaov params`` and ``sensaov check`` print: a scene's parameters, and their checks.

``params``: the selected parameters, what was left out, and why; text and ``--json`` come from
one :class:`ParameterInventory`, so they agree. ``check``: reverse mode against finite
differences, and duality; its rows are the render stage's results, read through the protocols
below so that this stage never imports the renderer.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

from sensaov_cli.buffer.model import ExcludedParam, ParamRecord, TextureSource
from sensaov_cli.outputs.tables import format_table

_PARAMS_NOTES = {
    "unverified": "UNVERIFIED", "biased": "BIASED", "suspect": "SUSPECT",
    "no_gradient": "NO GRADIENT",
}  # fmt: skip
# The keys of a selected parameter in params --json, in their order.
_SELECTED_KEYS = ("key", "type", "owners", "plugin", "shape", "is_texture", "flags", "verified",
                  "trust", "note", "texture_file", "converted", "estimator", "repair")  # fmt: skip


@dataclass(frozen=True)
class ParameterInventory:
    variant: str
    objects: tuple[str, ...]
    selected: tuple[ParamRecord, ...]
    excluded: tuple[ExcludedParam, ...]
    split: dict[str, tuple[str, ...]]
    textures: dict[str, TextureSource]
    # what sensaov changed in the scene: what, why, where, and whether it alters the image
    changes: tuple[tuple[str, str, str, bool], ...]
    # key -> why run repairs it by finite differences (budget permitting): render/verify/repair.py
    repairs: dict[str, str] = field(default_factory=dict)


def params_dict(loaded: ParameterInventory) -> dict[str, Any]:
    """What ``sensaov params --json`` prints (docs/job-spec.md)."""
    selected = []
    for record in loaded.selected:
        texture = loaded.textures.get(record.key)
        entry = asdict(record) | {
            "verified": record.verified,
            "texture_file": texture.file if texture else None,
            "converted": texture.converted if texture else False,
            "repair": loaded.repairs.get(record.key),
        }
        selected.append({key: entry[key] for key in _SELECTED_KEYS})
    return {
        "variant": loaded.variant,
        "objects": list(loaded.objects),
        "selected": selected,
        "excluded": [asdict(item) for item in loaded.excluded],
        "split_bsdfs": {name: list(shapes) for name, shapes in loaded.split.items()},
        "scene_changes": [
            {"what": what, "why": why, "where": where, "alters_image": alters}
            for what, why, where, alters in loaded.changes
        ],
    }


def params_text(loaded: ParameterInventory, *, show_all: bool = False) -> str:
    rows = [("key", "type", "owners", "plugin", "shape", "notes")]
    for info in loaded.selected:
        notes = list(info.flags)
        if info.is_texture:
            converted = loaded.textures[info.key].converted
            notes.append("texture, 8-bit -> float" if converted else "texture")
        if not info.verified:
            notes.append(_PARAMS_NOTES[info.trust])
        if info.key in loaded.repairs:
            notes.append("REPAIRED" if not info.is_texture else "NOT REPAIRED (texture)")
        shape = "x".join(str(n) for n in info.shape)
        rows.append(
            (info.key, info.type, ",".join(info.owners), info.plugin, shape, ", ".join(notes))
        )
    lines = [f"{len(loaded.selected)} parameters selected over {len(loaded.objects)} objects"]
    lines += format_table(rows)
    lines += _unverified_legend(loaded)
    if loaded.repairs:
        lines += [
            "",
            "REPAIRED: known wrong in reverse mode; run computes them again by central differences "
            "(repair.budget permitting; textures never: two renders per texel) - "
            'docs/verification.md, "Repairs"',
        ]
    if loaded.textures:
        lines += ["", "textures in the buffer:"]
        for key, source in loaded.textures.items():
            how = "converted from 8-bit to float so its texels get gradients"
            lines.append(f"  {key}: {source.file} ({how if source.converted else 'float'})")
    if loaded.split:
        lines += ["", "shared BSDFs split into one copy per object (parameters.shared: split):"]
        lines += [f"  {name} -> {', '.join(shapes)}" for name, shapes in loaded.split.items()]
    lines += _changes(loaded)
    lines += _excluded(loaded, show_all)
    return "\n".join(lines)


def _unverified_legend(loaded: ParameterInventory) -> list[str]:
    notes = sorted(
        {(_PARAMS_NOTES[i.trust], i.note) for i in loaded.selected if i.trust != "verified"}
    )
    if not notes:
        return []
    head = "gradients sensaov does not stand behind (left out of object and type views):"
    return ["", head] + [f"  - {label}: {note}" for label, note in notes]


def _changes(loaded: ParameterInventory) -> list[str]:
    if not loaded.changes:
        return []
    lines = ["", "what sensaov changed in the scene before loading it (your files are untouched):"]
    for what, why, where, alters in loaded.changes:
        mark = "!" if alters else "-"  # M is measured on another image than the scene's
        lines.append(f"  {mark} {what}{f' ({where})' if where else ''}: {why}")
    if any(alters for *_, alters in loaded.changes):
        lines.append("  (!: the image differentiated is not the one the scene renders)")
    return lines


def _excluded(loaded: ParameterInventory, show_all: bool) -> list[str]:
    by_reason: dict[str, list[str]] = defaultdict(list)
    for item in loaded.excluded:
        by_reason[item.reason].append(item.key)
    lines = ["", f"{len(loaded.excluded)} parameters left out:"]
    for reason, keys in sorted(by_reason.items(), key=lambda kv: -len(kv[1])):
        if show_all or len(keys) <= 3:
            lines.append(f"  {reason}: {', '.join(keys)}")
        else:
            lines.append(f"  {reason}: {len(keys)} keys (e.g. {keys[0]}; --all lists them)")
    return lines


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
        error = "-" if c.method == "same seed" else f"{c.standard_error:.1e}"
        contradicts = c.claimed_verified and c.verdict == "disagrees"
        verdict = c.verdict + ("  <-- CONTRADICTS THE TABLE" if contradicts else "")
        # c.claimed: the table's own label (biased kinds say biased)
        numbers = (f"{c.adjoint:+.3e}", f"{c.finite_difference:+.3e}", error, verdict)
        rows.append((c.key, c.plugin, c.type, c.claimed, c.method, *numbers))
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
        duality = (f"{d.reverse:+.4e}", f"{d.forward:+.4e}", f"{d.duality_error:.1e}")
        table.append(
            (d.objective, d.key, d.direction, d.trust, *duality, central, error, d.verdict)
        )
    return "\n".join([head, *format_table(table)])
