"""``$name`` scene arguments as Mitsuba 3.9.1's parser substitutes them (pure Python).

One table is shared by the main file and every file it includes: job arguments first,
``<default>`` adds a name only if it is absent (so defaults leak out of included files), plain
substring replacement longest name first, ``\\$`` escapes a dollar. A ``$`` left over is an
error at its file and line, and so is a job argument the scene never uses (Mitsuba refuses
both). The reference is ``substitute_parameters`` in ``src/core/parser.cpp``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from sensaov_cli.errors import SceneError

_SHOWN = 60  # characters of a long value shown in a message
_PARAMETER_NAME = re.compile(r"[A-Za-z0-9_]*")


def shorten(value: str) -> str:
    """A value as a message shows it: at most 60 characters and an ellipsis."""
    return value if len(value) <= _SHOWN else value[:_SHOWN] + "…"


@dataclass(frozen=True)
class SceneArgument:
    """A ``$name`` the scene was expanded with: its value and where it came from."""

    value: str
    origin: str  # "job", or the file:line of the scene's <default>


@dataclass
class _Parameter:
    key: str  # "$name"
    value: str
    origin: str
    used: bool  # Mitsuba's flag: a job argument never used is an error, a default never is
    substituted: bool = False


class Parameters:
    """Mitsuba's SortedParameters: one table for the main file and all its includes."""

    def __init__(self, scene_args: Mapping[str, object]) -> None:
        # Mitsuba turns every keyword argument into text with Python's str().
        given = [_Parameter(f"${k}", str(v), "job", False) for k, v in scene_args.items()]
        self.table = sorted(given, key=lambda p: -len(p.key))

    def default(self, name: str, value: str, origin: str) -> None:
        if any(p.key == f"${name}" for p in self.table):
            return  # job arguments and earlier defaults win
        new = _Parameter(f"${name}", value, origin, True)
        shorter = (i for i, p in enumerate(self.table) if len(new.key) > len(p.key))
        self.table.insert(next(shorter, len(self.table)), new)  # longest names first

    def substitute(self, value: str, origin: str) -> str:
        for param in self.table:
            pos = value.find(param.key)
            while pos != -1:
                if pos > 0 and value[pos - 1] == "\\":
                    pos += len(param.key)
                else:
                    value = value[:pos] + param.value + value[pos + len(param.key) :]
                    param.used = param.substituted = True
                    pos += len(param.value)
                pos = value.find(param.key, pos)
        _refuse_unresolved(value, origin)
        return value.replace("\\$", "$")

    def arguments(self) -> dict[str, SceneArgument]:
        """The arguments the scene text actually used, with their values."""
        return {p.key[1:]: SceneArgument(p.value, p.origin) for p in self.table if p.substituted}

    def refuse_unused(self, path: Path) -> None:
        unused = [p.key[1:] for p in self.table if p.origin == "job" and not p.used]
        if unused:
            known = sorted(p.key[1:] for p in self.table if p.used)
            raise SceneError(
                f"scene argument {unused[0]!r} is not used by the scene",
                where=str(path),
                hint=f"arguments the scene has: {', '.join(known) or 'none'}",
            )


def _refuse_unresolved(value: str, origin: str) -> None:
    for pos, char in enumerate(value):
        if char != "$" or (pos > 0 and value[pos - 1] == "\\"):
            continue
        name = _PARAMETER_NAME.match(value, pos + 1)
        name_text = shorten(name.group() if name else "")
        if not name_text:
            raise SceneError(
                "a '$' that names no scene argument", where=origin, hint="write \\$ for a '$'"
            )
        raise SceneError(
            f"scene argument ${name_text} has no value",
            where=origin,
            hint=f"set it in the job (scene_args: {{{name_text}: ...}}) "
            f'or give the scene a <default name="{name_text}" value="..."/>',
        )
