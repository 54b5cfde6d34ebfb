"""What ``sensaov params`` prints: the selected parameters and the reasons for the rest."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import asdict
from typing import Any

from sensaov_cli.outputs.tables import format_table
from sensaov_cli.render.scene import LoadedScene


def params_dict(loaded: LoadedScene) -> dict[str, Any]:
    return {
        "variant": loaded.variant,
        "objects": list(loaded.objects),
        "selected": [asdict(info) for info in loaded.selected],
        "excluded": [asdict(item) for item in loaded.excluded],
        "split_bsdfs": {name: list(shapes) for name, shapes in loaded.split.items()},
    }


def params_text(loaded: LoadedScene, *, show_all: bool = False) -> str:
    rows = [("key", "type", "owners", "plugin", "shape", "notes")]
    for info in loaded.selected:
        notes = list(info.flags)
        if info.is_texture:
            notes.append("texture, 8-bit -> float" if info.converted else "texture")
        if not info.verified:
            notes.append("UNVERIFIED")
        shape = "x".join(str(n) for n in info.shape)
        rows.append(
            (info.key, info.type, ",".join(info.owners), info.plugin, shape, ", ".join(notes))
        )
    lines = [f"{len(loaded.selected)} parameters selected over {len(loaded.objects)} objects"]
    lines += format_table(rows)
    lines += _unverified_legend(loaded)
    lines += _textures(loaded)
    lines += _split(loaded)
    lines += _excluded(loaded, show_all)
    return "\n".join(lines)


def _unverified_legend(loaded: LoadedScene) -> list[str]:
    notes = sorted({info.note for info in loaded.selected if not info.verified})
    return (
        ["", "UNVERIFIED gradients (do not trust their ranking blindly):"]
        + [f"  - {n}" for n in notes]
        if notes
        else []
    )


def _textures(loaded: LoadedScene) -> list[str]:
    textures = [info for info in loaded.selected if info.is_texture]
    if not textures:
        return []
    lines = ["", "textures in the buffer:"]
    for info in textures:
        how = (
            "converted from 8-bit to float so its texels get gradients"
            if info.converted
            else "float"
        )
        lines.append(f"  {info.key}: {info.texture_file} ({how})")
    return lines


def _split(loaded: LoadedScene) -> list[str]:
    if not loaded.split:
        return []
    lines = ["", "shared BSDFs split into one copy per object (parameters.shared: split):"]
    lines += [f"  {name} -> {', '.join(shapes)}" for name, shapes in loaded.split.items()]
    return lines


def _excluded(loaded: LoadedScene, show_all: bool) -> list[str]:
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
