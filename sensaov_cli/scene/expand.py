"""Expand a scene into one XML tree the way Mitsuba 3.9.1's parser reads it (pure Python).

sensaov rewrites the scene before Mitsuba sees it, so the rewrite has to see what Mitsuba
would: the reference is ``src/core/parser.cpp`` (``parse_xml_node``, ``substitute_parameters``,
``parse_file_impl``), and what 3.9.1 was measured to do. Includes, ``$name`` arguments,
``<path>`` and ``<alias>`` are expanded; plugin file names are resolved as Mitsuba resolves
them at instantiation (against the main file's folder and its ``<path>`` folders, never an
included file's folder) and made absolute, so a scene loaded from a string resolves them the
same. Files of a format version below 2.0 get Mitsuba's upgrade (``transform_upgrade``), per
object by the version of the file it was read from, and what else 3.9.1 lacks of 0.5/0.6 is
upgraded or refused (legacy.py). Missing files, unknown elements and plugins, unsupported old
properties are gathered and reported together (``Refusals``, source.py).
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from sensaov_cli.errors import SceneError
from sensaov_cli.limits import regular_file
from sensaov_cli.scene.declared_sizes import check_declared_size
from sensaov_cli.scene.legacy import refuse_unknown_plugins, srgb_element, upgrade_legacy
from sensaov_cli.scene.source import (
    OBJECT_TAGS,
    Change,
    Refusals,
    is_object,
    read_xml,
    user_attributes,
    where,
)

MAX_INCLUDE_DEPTH = 15  # Mitsuba's ParserConfig.max_include_depth
# Every tag Mitsuba 3.9.1's parser knows (interpret_tag); any other is "an unsupported XML
# element" to it, the 0.6 <shapegroup> included.
_KNOWN_TAGS = OBJECT_TAGS | frozenset(
    "boolean integer float string point vector rgb spectrum transform"
    " translate rotate scale lookat matrix ref include alias default path".split()
)


@dataclass(frozen=True)
class ExpandedScene:
    root: ET.Element
    files: tuple[Path, ...]  # every file the scene reads (XML first); names not found as written
    search_path: tuple[Path, ...]  # where Mitsuba looks for names still relative, first wins
    arguments: dict[str, SceneArgument]
    changes: tuple[Change, ...]  # what reading it changed: old formats upgraded


def expand_scene(path: Path, scene_args: Mapping[str, object]) -> ExpandedScene:
    expansion = _Expansion(Parameters(scene_args))
    main = _Context(path, [path.parent.absolute()], ())
    root = expansion.file(main)
    if root.tag != "scene":
        raise SceneError(f"root element is <{root.tag}>, expected <scene>", where=where(root))
    expansion.finish(root, main)
    expansion.refusals.raise_all(str(path))  # every missing file and unsupported property
    return ExpandedScene(
        root,
        tuple(dict.fromkeys(expansion.files)),
        tuple(dict.fromkeys(main.resolver)),
        expansion.parameters.arguments(),
        tuple(expansion.changes),
    )


@dataclass
class _Context:
    """One file being read: Mitsuba's per-file parser state.

    Measured on 3.9.1: a file's resolver is its includer's, with the includer's folder
    prepended; its own folder is searched first only for ``<include>`` and ``<path>``, so a
    ``<spectrum filename>`` next to an included file is not found (one next to its includer
    is).
    """

    path: Path
    resolver: list[Path]  # search folders, first wins; <path> prepends to it
    chain: tuple[Path, ...]  # this file and the files that include it, outermost first

    def here(self) -> list[Path]:
        """The folders an ``<include>`` or ``<path>`` in this file is looked for in."""
        return [self.path.parent.absolute(), *self.resolver]


@dataclass
class _Expansion:
    parameters: Parameters
    ids: dict[str, str] = field(default_factory=dict)  # id -> where it is defined
    aliases: dict[str, str] = field(default_factory=dict)  # alias -> the id it stands for
    files: list[Path] = field(default_factory=list)
    filenames: list[ET.Element] = field(default_factory=list)  # resolved once <path>s are known
    legacy: set[str] = field(default_factory=set)  # files older than format 2.0
    refusals: Refusals = field(default_factory=Refusals)  # gathered: one pass reports all
    changes: list[Change] = field(default_factory=list)

    def file(self, context: _Context) -> ET.Element:
        root = read_xml(context.path)
        self.files.append(context.path)
        if _version(root) < (2, 0, 0):
            self.legacy.add(str(context.path))
        context.chain += (context.path,)
        self._attributes(root)
        if root.get("type", "scene") != "scene":
            self._register(root)
        for child in list(root):
            self._element(root, child, context, at_root=True)
        return root

    def finish(self, root: ET.Element, main: _Context) -> None:
        self.parameters.refuse_unused(main.path)
        for ref in root.iter("ref"):
            ref.set("id", self.aliases.get(ref.get("id", ""), ref.get("id", "")))
        for element in self.filenames:
            with self.refusals.gathered():
                resolved = _existing(element.get("value", ""), main.resolver, where(element))
                check_declared_size(resolved, where(element))  # a gigapixel, a billion vertices
                self.files.append(resolved)
                element.set("value", str(resolved))
        upgrade_legacy(root, self.legacy, self.changes, self.refusals)
        refuse_unknown_plugins(root, self.refusals)

    def _attributes(self, element: ET.Element) -> None:
        for key, value in user_attributes(element):
            if "$" in value:
                element.set(key, self.parameters.substitute(value, where(element)))

    def _element(
        self, parent: ET.Element, element: ET.Element, context: _Context, at_root: bool
    ) -> None:
        self._attributes(element)
        if element.tag == "srgb" and str(context.path) in self.legacy:
            srgb_element(element, self.changes, self.refusals)
        if element.tag not in _KNOWN_TAGS:
            self.refusals.add(
                f"<{element.tag}> is not an element Mitsuba 3 reads",
                where(element),
                hint='write <shape type="shapegroup" id="..."> (the 0.6 <shapegroup> tag is gone)'
                if element.tag == "shapegroup"
                else "see Mitsuba's scene format documentation",
            )
            parent.remove(element)
            return
        if element.tag in ("include", "default", "path", "alias"):
            index = list(parent).index(element)
            parent.remove(element)
            if element.tag == "include":
                parent[index:index] = self._include(element, context)
            elif element.tag == "default":
                self._default(element)
            elif element.tag == "path":
                self._path(element, context, at_root)
            else:
                self._alias(element)
            return
        if is_object(element):
            self._register(element)
        elif element.tag == "spectrum" and element.get("filename"):
            with self.refusals.gathered():
                resolved = _existing(element.get("filename", ""), context.resolver, where(element))
                self.files.append(resolved)
                element.set("filename", str(resolved))
        elif (
            element.tag == "string" and element.get("name") == "filename" and parent.tag != "scene"
        ):
            self.filenames.append(element)
        for child in list(element):
            self._element(element, child, context, at_root=False)

    def _register(self, element: ET.Element) -> None:
        identifier = element.get("id")
        if identifier is None:
            return
        if identifier in self.ids:
            raise SceneError(
                f"duplicate id {shorten(identifier)!r} (first defined at {self.ids[identifier]})",
                where=where(element),
            )
        self.ids[identifier] = where(element)

    def _include(self, element: ET.Element, context: _Context) -> list[ET.Element]:
        """The file is looked for next to the including file, then in the folders of the files
        that include that one and the ``<path>`` folders so far; a cycle is refused (Mitsuba
        would only stop at its depth limit, which is kept)."""
        name = _required(element, "filename")
        folders = context.here()
        try:
            path = _existing(name, folders, where(element), what="included file")
        except SceneError as exc:  # gathered: the rest of the scene is still checked
            self.refusals.found.append(exc)
            return []
        _refuse_nesting(path, context.chain, where(element))
        root = self.file(_Context(path, folders, context.chain))
        if root.get("type", "scene") == "scene":
            # Only objects cross over; properties and refs on an included <scene> are dropped.
            return [child for child in root if is_object(child)]
        root.attrib.pop("version")
        root.attrib.pop("name", None)
        if element.get("name"):
            root.set("name", element.get("name", ""))
        return [root]

    def _default(self, element: ET.Element) -> None:
        name = _required(element, "name")
        if not name:
            raise SceneError("<default>: name must be non-empty", where=where(element))
        self.parameters.default(name, _required(element, "value"), where(element))

    def _path(self, element: ET.Element, context: _Context, at_root: bool) -> None:
        if not at_root:
            raise SceneError("<path> can only be a child of the root element", where=where(element))
        value = _required(element, "value")
        folder = _resolve(value, context.here(), where(element))
        if not _exists(folder, where(element)):
            raise SceneError(f'<path>: folder "{shorten(value)}" not found', where=where(element))
        context.resolver.insert(0, folder)

    def _alias(self, element: ET.Element) -> None:
        source, alias = _required(element, "id"), _required(element, "as")
        if alias in self.ids:
            raise SceneError(f'alias destination id "{alias}" already exists', where=where(element))
        if source not in self.ids:
            raise SceneError(
                f'alias source id "{source}" not found',
                where=where(element),
                hint="an alias must come after the object it names",
            )
        self.aliases[alias] = self.aliases.get(source, source)
        self.ids[alias] = where(element)


def _required(element: ET.Element, attribute: str) -> str:
    value = element.get(attribute)
    if value is None:
        raise SceneError(
            f'missing required attribute "{attribute}" in <{element.tag}>', where=where(element)
        )
    return value


def _version(root: ET.Element) -> tuple[int, ...]:
    text = root.get("version")
    if text is None:
        raise SceneError(
            f"missing version attribute in root element <{root.tag}>", where=where(root)
        )
    parts = text.strip().split(".")
    if len(parts) != 3 or not all(part.isdigit() for part in parts):
        raise SceneError(f'invalid version number "{text}"', where=where(root))
    return tuple(int(part) for part in parts)


def _resolve(name: str, folders: list[Path], origin: str) -> Path:
    """Mitsuba's FileResolver.resolve: the first folder holding ``name``, else ``name``."""
    path = Path(name)
    if path.is_absolute():
        return path
    for folder in folders:
        if _exists(folder / path, origin):
            return folder / path
    return path


def _existing(name: str, folders: list[Path], origin: str, what: str = "file") -> Path:
    """``name`` resolved, refused where Mitsuba would fail to open it (run and validate alike),
    or where it would block or never end reading it (a FIFO, a device: a regular file only)."""
    path = _resolve(name, folders, origin)
    if not _exists(path, origin):
        looked = "" if path.is_absolute() else ", ".join(str(p) for p in dict.fromkeys(folders))
        raise SceneError(
            f'{what} "{shorten(name)}" not found',
            where=origin,
            hint=f"looked in {looked}" if looked else None,
        )
    regular_file(path, what, where=origin, error=SceneError)
    return path.absolute()


def _exists(path: Path, origin: str) -> bool:
    try:
        return path.exists()
    except OSError as exc:  # a name too long for the file system, say
        raise SceneError(
            f'cannot look for "{shorten(str(path))}": {exc.strerror or exc}', where=origin
        ) from exc


def _refuse_nesting(path: Path, chain: tuple[Path, ...], origin: str) -> None:
    real = [os.path.realpath(p) for p in chain]
    if os.path.realpath(path) in real:
        start = real.index(os.path.realpath(path))
        names = " -> ".join(p.name for p in (*chain[start:], path))
        raise SceneError(f"include cycle: {names}", where=origin)
    if len(chain) >= MAX_INCLUDE_DEPTH:
        raise SceneError(
            f"include depth exceeds Mitsuba's limit of {MAX_INCLUDE_DEPTH}", where=origin
        )


# --- $name arguments: Mitsuba's SortedParameters ---------------------------------------

_SHOWN = 60  # characters of a long value shown in a message
_UNRESOLVED = re.compile(r"(?<!\\)\$([A-Za-z0-9_]*)")  # a "$" not escaped as "\$"


def shorten(value: str) -> str:
    """A value as a message shows it: at most 60 characters and an ellipsis."""
    return value if len(value) <= _SHOWN else value[:_SHOWN] + "…"


@dataclass(frozen=True)
class SceneArgument:
    """A ``$name`` the scene was expanded with: its value and where it came from."""

    value: str
    origin: str  # "job", or the file:line of the scene's <default>


class Parameters:
    """Mitsuba's SortedParameters: one table for the main file and all its includes.

    Job arguments come first; a ``<default>`` adds a name only where it is absent (so defaults
    leak out of included files); substitution is plain substring replacement, longest name
    first, on every attribute in document order; ``\\$`` escapes a dollar.
    """

    def __init__(self, scene_args: Mapping[str, object]) -> None:
        # Mitsuba turns every keyword argument into text with Python's str().
        self.table = {name: SceneArgument(str(v), "job") for name, v in scene_args.items()}
        self.used: set[str] = set()  # a job argument never used is an error, a default never

    def default(self, name: str, value: str, origin: str) -> None:
        self.table.setdefault(name, SceneArgument(value, origin))  # job's and earlier ones win

    def _longest_first(self) -> list[str]:
        return sorted(self.table, key=len, reverse=True)  # stable: equal lengths in table order

    def substitute(self, value: str, origin: str) -> str:
        for name in self._longest_first():
            key, replacement = f"${name}", self.table[name].value
            pos = value.find(key)
            while pos != -1:
                if pos > 0 and value[pos - 1] == "\\":
                    pos += len(key)
                else:
                    value = value[:pos] + replacement + value[pos + len(key) :]
                    self.used.add(name)
                    pos += len(replacement)
                pos = value.find(key, pos)
        _refuse_unresolved(value, origin)
        return value.replace("\\$", "$")

    def arguments(self) -> dict[str, SceneArgument]:
        """The arguments the scene text actually used, with their values."""
        return {name: self.table[name] for name in self._longest_first() if name in self.used}

    def refuse_unused(self, path: Path) -> None:
        jobs = [name for name in self._longest_first() if self.table[name].origin == "job"]
        unused = [name for name in jobs if name not in self.used]
        if unused:
            known = sorted(name for name in self.table if name not in unused)
            raise SceneError(
                f"scene argument {unused[0]!r} is not used by the scene",
                where=str(path),
                hint=f"arguments the scene has: {', '.join(known) or 'none'}",
            )


def _refuse_unresolved(value: str, origin: str) -> None:
    found = _UNRESOLVED.search(value)
    if found is None:
        return
    name_text = shorten(found.group(1))
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
