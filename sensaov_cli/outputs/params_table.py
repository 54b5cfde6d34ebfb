"""What ``sensaov params`` prints: the selected parameters, what was left out, and why.

The text and ``--json`` come from one :class:`ParameterInventory`, so they always agree; the
aligned table is tables.py's. Plain text only, like every terminal table.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import asdict, dataclass, field
from typing import Any

from sensaov_cli.buffer.model import ExcludedParam, ParamRecord, TextureSource
from sensaov_cli.outputs.tables import format_table

_PARAMS_NOTES = {
    "unverified": "UNVERIFIED", "biased": "BIASED", "suspect": "SUSPECT",
    "no_gradient": "NO GRADIENT",
}  # fmt: skip


@dataclass(frozen=True)
class ParameterInventory:
    """What ``sensaov params`` reports of a loaded scene, as plain data."""

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
    return {
        "variant": loaded.variant,
        "objects": list(loaded.objects),
        "selected": [
            {
                **_selected_entry(info, loaded.textures.get(info.key)),
                "estimator": info.estimator,
                "repair": loaded.repairs.get(info.key),
            }
            for info in loaded.selected
        ],
        "excluded": [asdict(item) for item in loaded.excluded],
        "split_bsdfs": {name: list(shapes) for name, shapes in loaded.split.items()},
        "scene_changes": [
            {"what": what, "why": why, "where": where, "alters_image": alters}
            for what, why, where, alters in loaded.changes
        ],
    }


def _selected_entry(record: ParamRecord, texture: TextureSource | None) -> dict[str, Any]:
    entry = asdict(record)
    plugin = entry.pop("plugin")  # the order these keys always had in params --json
    return {
        **{key: entry[key] for key in ("key", "type", "owners")},
        "plugin": plugin,
        **{key: entry[key] for key in ("shape", "is_texture", "flags")},
        "verified": record.verified,
        **{key: entry[key] for key in ("trust", "note")},
        "texture_file": texture.file if texture else None,
        "converted": texture.converted if texture else False,
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
    lines += _repairs_legend(loaded)
    lines += _textures(loaded)
    lines += _split(loaded)
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


def _repairs_legend(loaded: ParameterInventory) -> list[str]:
    if not loaded.repairs:
        return []
    return [
        "",
        "REPAIRED: known wrong in reverse mode; run computes them again by central differences "
        "(repair.budget permitting; textures never: two renders per texel) - "
        'docs/verification.md, "Repairs"',
    ]


def _textures(loaded: ParameterInventory) -> list[str]:
    if not loaded.textures:
        return []
    lines = ["", "textures in the buffer:"]
    for key, source in loaded.textures.items():
        how = (
            "converted from 8-bit to float so its texels get gradients"
            if source.converted
            else "float"
        )
        lines.append(f"  {key}: {source.file} ({how})")
    return lines


def _split(loaded: ParameterInventory) -> list[str]:
    if not loaded.split:
        return []
    lines = ["", "shared BSDFs split into one copy per object (parameters.shared: split):"]
    lines += [f"  {name} -> {', '.join(shapes)}" for name, shapes in loaded.split.items()]
    return lines


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
