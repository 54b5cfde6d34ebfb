"""Read a job file as ``yaml.safe_load`` would, also keeping the line of every key path.

``yaml.safe_load`` forgets where things were and silently keeps the last of two equal keys. We
compose the node tree with the same ``SafeLoader``, walk it once to note the line of each key
path and refuse duplicate keys, then construct the data from the same tree, so the data is
exactly what ``safe_load`` returns.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from sensaov_cli.errors import SpecError
from sensaov_cli.limits import read_regular

KeyPath = tuple[Any, ...]
_MERGE_TAG = "tag:yaml.org,2002:merge"
MAX_JOB_BYTES = 16 << 20
_PLAIN_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def format_key_path(path: KeyPath) -> str:
    """``("objectives", 1, "region")`` -> ``objectives[1].region``."""
    text = ""
    for part in path:
        if isinstance(part, int) and not isinstance(part, bool):
            text += f"[{part}]"
        elif isinstance(part, str) and _PLAIN_KEY.fullmatch(part):
            text += f".{part}" if text else part
        else:
            # Odd keys (spaces, newlines, numbers) are quoted so the path stays one line.
            text += f"[{json.dumps(part) if isinstance(part, str) else repr(part)}]"
    return text


def spec_error(
    shown: str, line: int | None, path: KeyPath, message: str, hint: str | None = None
) -> SpecError:
    """A SpecError located as ``<job>:<line>: <key path>``, on one line whatever the inputs."""
    where = shown if line is None else f"{shown}:{line}"
    if path:
        where += f": {format_key_path(path)}"
    return SpecError(_one_line(message), where=where, hint=_one_line(hint) if hint else None)


def _one_line(text: str) -> str:
    return " ".join(text.split())


@dataclass(frozen=True)
class YamlDocument:
    """The data of a job file and the line (1-based) where each key path is written."""

    data: Any
    lines: dict[KeyPath, int]

    def line_of(self, path: KeyPath) -> int | None:
        """The line of ``path``, or of its nearest written ancestor (for a missing key)."""
        for end in range(len(path), -1, -1):
            line = self.lines.get(tuple(path[:end]))
            if line is not None:
                return line
        return None


def read_yaml(path: Path, shown: str) -> YamlDocument:
    """Read and parse ``path``; every failure is a SpecError located in ``shown``."""
    # A regular file of sane size: a FIFO would block forever, /dev/zero never end.
    raw = read_regular(path, "job file", cap=MAX_JOB_BYTES, error=SpecError)
    try:
        return _parse(raw, shown)
    except yaml.MarkedYAMLError as exc:
        raise _syntax_error(exc, shown) from None
    except yaml.YAMLError as exc:
        raise spec_error(shown, None, (), f"YAML error: {exc}") from None
    except RecursionError:
        raise spec_error(shown, None, (), "YAML nested too deeply") from None


def _parse(raw: bytes, shown: str) -> YamlDocument:
    loader = yaml.SafeLoader(raw)
    try:
        node = loader.get_single_node()
        if node is None:
            raise spec_error(shown, None, (), "the job file is empty", "start with 'version: 1'")
        lines: dict[KeyPath, int] = {(): node.start_mark.line + 1}
        _walk(loader, node, (), lines, set(), shown)
        data = loader.construct_document(node)
    finally:
        loader.dispose()
    return YamlDocument(data, lines)


def _walk(
    loader: yaml.SafeLoader,
    node: yaml.Node,
    path: KeyPath,
    lines: dict[KeyPath, int],
    seen: set[int],
    shown: str,
) -> None:
    """Note the line of every key and item below ``node``; refuse duplicate keys."""
    # An alias repeats a node; walking it once keeps "billion laughs" documents cheap.
    if id(node) in seen:
        return
    seen.add(id(node))
    if isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            lines.setdefault(path + (index,), item.start_mark.line + 1)
            _walk(loader, item, path + (index,), lines, seen, shown)
    elif isinstance(node, yaml.MappingNode):
        first: dict[Any, int] = {}
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == _MERGE_TAG:
                continue  # merge keys and complex keys are left to the constructor
            key = loader.construct_object(key_node)
            line = key_node.start_mark.line + 1
            if key in first:
                raise spec_error(
                    shown,
                    line,
                    path + (key,),
                    f"duplicate key (first given on line {first[key]})",
                    "YAML would silently keep only the last one; remove one",
                )
            first[key] = line
            lines.setdefault(path + (key,), line)
            _walk(loader, value_node, path + (key,), lines, seen, shown)


def _syntax_error(exc: yaml.MarkedYAMLError, shown: str) -> SpecError:
    mark = exc.problem_mark or exc.context_mark
    line = mark.line + 1 if mark is not None else None
    parts = [part for part in (exc.context, exc.problem) if part]
    return spec_error(shown, line, (), "invalid YAML: " + ", ".join(parts))
