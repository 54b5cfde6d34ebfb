"""Scene XML files with the file and line of every element, what is told there, and the way
back from Mitsuba.

Elements read here carry their origin (``file:line``) in a private attribute that survives
``copy.deepcopy`` (split BSDFs, inlined textures, sensor copies keep pointing at the user's
line) and is never written out. The changes preparing a scene makes (:class:`Change`) and what
Mitsuba would refuse (:class:`Refusals`, gathered over the whole scene so that a user fixes
everything in one round, before Mitsuba starts) are told at those lines too.
"""

from __future__ import annotations

import copy
import re
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from xml.parsers import expat

from sensaov_cli.errors import SceneError
from sensaov_cli.limits import read_regular

OBJECT_TAGS = frozenset(
    "scene bsdf emitter field film integrator medium phase rfilter sampler sensor shape texture"
    " volume".split()
)
# Clark notation keeps the key out of every plain attribute lookup a rewrite does.
_WHERE = "{urn:sensaov}where"
# Mitsuba's location in a string-loaded scene, e.g. "Error while loading string (line 3, col 5): "
_MITSUBA_LOCATION = re.compile(
    r"(?:Error while loading |While loading |At )?string \(line (\d+), col \d+\):?\s*"
)
MAX_XML_BYTES = 256 << 20  # far above any scene file; /dev/zero or a disk image is refused
_LONG_QUOTED = re.compile(r'"([^"]{61,})"')  # a long value Mitsuba echoes, shown shortened
_MITSUBA_SOURCE_TAG = re.compile(r"\[[\w.]+:\d+\]\s*")  # "[parser.cpp:451] "
_XML_ESCAPES = {"&": "&amp;", "<": "&lt;", '"': "&quot;"} | {c: f"&#{ord(c)};" for c in "\n\r\t"}
# Mitsuba substitutes parameters again on the text it is given: a literal "$" left by the
# expansion (the user wrote "\$") must reach it escaped.
_ATTRIBUTE_ESCAPES = str.maketrans({**_XML_ESCAPES, "$": "\\$"})


def is_object(element: ET.Element) -> bool:
    """An element Mitsuba instantiates (``<spectrum type=..>`` is a texture object)."""
    return element.tag in OBJECT_TAGS or (element.tag == "spectrum" and "type" in element.attrib)


def read_xml(path: Path) -> ET.Element:
    """Parse ``path``; every element remembers the line its start tag is on."""
    data = read_regular(path, "scene file", cap=MAX_XML_BYTES, error=SceneError)
    parser = expat.ParserCreate(_fallback_encoding(data))
    stack = [ET.Element("document")]  # the document holds the root element

    def start(tag: str, attrs: dict[str, str]) -> None:
        element = ET.SubElement(stack[-1], tag, attrs)
        element.set(_WHERE, f"{path}:{parser.CurrentLineNumber}")
        stack.append(element)

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: stack.pop()
    try:
        parser.Parse(data, True)
    except expat.ExpatError as exc:
        message = f"malformed XML: {expat.ErrorString(exc.code)}"
        raise SceneError(message, where=f"{path}:{exc.lineno}") from exc
    return stack[0][0]


def _fallback_encoding(data: bytes) -> str | None:
    """Latin-1 for a file that declares no encoding and is not UTF-8 (Mitsuba's parser loads
    such files, often written by Windows tools); None: the file says, or is UTF-8."""
    head = data[:200].lstrip(b"\xef\xbb\xbf")
    if head.startswith((b"\xff\xfe", b"\xfe\xff")):
        return None  # UTF-16, by its byte order mark
    if head.startswith(b"<?xml") and b"encoding" in head.split(b"?>", 1)[0]:
        return None
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        return "ISO-8859-1"
    return None


def where(element: ET.Element) -> str:
    """The user's ``file:line`` of ``element`` ("" for an element sensaov added)."""
    return element.get(_WHERE, "")


def user_attributes(element: ET.Element) -> list[tuple[str, str]]:
    """The attributes as the user wrote them (without the location sensaov keeps)."""
    return [(key, value) for key, value in element.attrib.items() if key != _WHERE]


def new_element(tag: str, attrib: dict[str, str], like: ET.Element) -> ET.Element:
    """An element sensaov writes; ``like`` lends it the user's line it stands for."""
    return ET.Element(tag, {**attrib, _WHERE: where(like)} if where(like) else attrib)


def detached_copy(element: ET.Element) -> ET.Element:
    """A deep copy whose objects carry no ids (ids are global in Mitsuba; the original keeps
    them). A ``<ref>`` keeps its id: it names the object it uses, and defines none."""
    clone = copy.deepcopy(element)
    for node in clone.iter():
        if node.tag != "ref":
            node.attrib.pop("id", None)
    return clone


def write_xml(root: ET.Element) -> tuple[str, tuple[str | None, ...]]:
    """The scene text, every element on a line of its own, and for each line the user's
    ``file:line`` (None: added), so that a load error Mitsuba reports as ``string (line L, col
    C)`` can be told at the user's file."""
    lines = list(_lines(root, 0))
    return "".join(f"{line}\n" for line, _ in lines), tuple(origin for _, origin in lines)


def _lines(element: ET.Element, depth: int) -> Iterator[tuple[str, str | None]]:
    attributes = "".join(
        f' {key}="{value.translate(_ATTRIBUTE_ESCAPES)}"' for key, value in user_attributes(element)
    )
    pad, origin = "  " * depth, element.get(_WHERE)
    if len(element) == 0:
        yield f"{pad}<{element.tag}{attributes}/>", origin
        return
    yield f"{pad}<{element.tag}{attributes}>", origin
    for child in element:
        yield from _lines(child, depth + 1)
    yield f"{pad}</{element.tag}>", origin


def locate_load_error(message: str, sources: tuple[str | None, ...]) -> tuple[str, str | None]:
    """Mitsuba's load error on the rewritten text -> (one-line message, user's file:line)."""
    text = _MITSUBA_SOURCE_TAG.sub("", message.strip())
    found = None
    match = _MITSUBA_LOCATION.search(text)
    if match:
        line = int(match.group(1))
        found = sources[line - 1] if 0 < line <= len(sources) else None
        text = text[: match.start()] + text[match.end() :]
    parts = [part.strip() for part in text.splitlines() if part.strip()]
    text = _LONG_QUOTED.sub(lambda m: f'"{m.group(1)[:60]}…"', " ".join(parts))
    return text or "Mitsuba could not load the scene", found


MITSUBA = "Mitsuba 3.9.1"


@dataclass(frozen=True)
class Change:
    """One thing sensaov changed in the scene before Mitsuba loads it, and why."""

    what: str
    why: str
    where: str  # the user's file:line it concerns ("" where the scene says nothing)
    alters_image: bool = False  # M is measured on another image than the scene renders


@dataclass
class Refusals:
    """Problems found so far, each a :class:`SceneError` with its file and line."""

    found: list[SceneError] = field(default_factory=list)

    def add(self, message: str, where: str, hint: str | None = None) -> None:
        self.found.append(SceneError(message, where=where, hint=hint))

    @contextmanager
    def gathered(self) -> Iterator[None]:
        """Run a step that may refuse the scene; its refusal is kept, and the pass goes on."""
        try:
            yield
        except SceneError as exc:
            self.found.append(exc)

    def raise_all(self, scene: str) -> None:
        """One error naming every problem found (the one itself where there is one)."""
        if len(self.found) == 1:
            raise self.found[0]
        if self.found:
            listed = "; ".join(f"[{i}] {exc}" for i, exc in enumerate(self.found, 1))
            raise SceneError(
                f"{len(self.found)} problems {MITSUBA} would refuse the scene for: {listed}",
                where=scene,
            )
