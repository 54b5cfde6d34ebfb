"""How a job file writes the classes of :mod:`.job`: pydantic schemas built from their fields.

A section (render, parameters, look_at, the job) is one mapping whose keys are its fields,
bar those the loader gives. A class written in several shapes is a tagged union of such
mappings, each taking the fields marked ``In`` that shape and the fields marked nowhere:
objectives by ``type``, channels by ``kind``, inspection cameras by the key that picks their
kind, and ``objective_camera`` as a sensor id, a mapping or null. Every mapping refuses an
unknown key before it looks at any value, and its values become the dataclass through the
class's own ``__init__``, so ``__post_init__`` checks hold for a job file too.

Only the markers of :mod:`.markers` import this module, when pydantic builds a schema; it
imports them back for type checking only.
"""

from __future__ import annotations

import dataclasses
import operator
import os
import types
from collections.abc import Callable
from dataclasses import MISSING, dataclass, field
from functools import cache, reduce
from pathlib import Path
from typing import (
    TYPE_CHECKING,
    Annotated,
    Any,
    Literal,
    Union,
    get_args,
    get_origin,
    get_type_hints,
)

from annotated_types import MinLen
from pydantic import GetCoreSchemaHandler
from pydantic_core import CoreSchema, core_schema

from sensaov_cli.job.plain_markers import Doc, Given, In, Setting
from sensaov_cli.job.problems import Problem, describe, did_you_mean

if TYPE_CHECKING:  # the markers call this module; it only reads their attributes
    from sensaov_cli.job.markers import JobPath, SensorOrPlaced, Tagged, TaggedByKey

_TEXT = Annotated[str, Setting(strict=True), MinLen(1)]  # a tag or a sensor id: fields.Text
# The error type of a value that picks no member of a union; its context says why.
UNION = "sensaov_union"


@dataclass(frozen=True)
class _Key:
    name: str
    hint: Any  # the field's type in this shape
    default: Any  # MISSING: the key is required


@dataclass(frozen=True)
class _Form:
    """One mapping a class is written as."""

    cls: type
    keys: list[_Key]
    ref: str  # the name of its definition in the JSON Schema
    owner: str = ""  # names the shape in an unknown-key error: " for type python"
    fixed: dict[str, Any] = field(default_factory=dict)  # fields the shape does not write
    unknown: Callable[[Any], Problem | None] = lambda key: None  # a better word for a key
    section: bool = False  # the whole class: its schema takes the class's name and docstring


def section_schema(cls: type, handler: GetCoreSchemaHandler) -> CoreSchema:
    """``cls`` as one mapping of all its fields."""
    return _mapping(_Form(cls, _keys(cls, None), cls.__name__, section=True), handler)


def tagged_schema(cls: type, marker: Tagged, handler: GetCoreSchemaHandler) -> CoreSchema:
    """``cls`` as one mapping per value of ``marker.field``, picked by that value."""
    tag = marker.field
    values: tuple[str, ...] = get_args(get_type_hints(cls)[tag])

    def tagged(key: _Key, value: str) -> _Key:
        # Within its shape the tag has the one value.
        return _Key(tag, Literal[value], MISSING) if key.name == tag else key

    shapes = {value: [tagged(key, value) for key in _keys(cls, value)] for value in values}
    members = {}
    for value, keys in _ordered(shapes, lambda value: tag).items():
        form = _Form(cls, keys, _camel(value) + marker.noun, owner=f" for {tag} {value}")
        members[f"{tag}: {value}"] = _mapping(form, handler)

    def pick(value: Any) -> str | None:
        chosen = value.get(tag) if isinstance(value, dict) else None
        return f"{tag}: {chosen}" if isinstance(chosen, str) and chosen in values else None

    return _union(members, pick, marker.expects, field=tag, choices=values)


def tagged_by_key_schema(
    cls: type, marker: TaggedByKey, handler: GetCoreSchemaHandler
) -> CoreSchema:
    """``cls`` as one mapping per key of ``marker.keys``, picked by the first present."""
    shapes = _ordered({key: _keys(cls, key) for key in marker.keys}, lambda key: key)

    def clash(key: Any) -> Problem | None:
        return Problem(marker.clash.format(key), at=(key,)) if key in marker.keys else None

    members = {}
    for (key, keys), owner in zip(shapes.items(), marker.owners, strict=True):
        form = _Form(cls, keys, _camel(key) + marker.noun, owner=owner, unknown=clash)
        members[f"with {key}"] = _mapping(form, handler)

    def pick(value: Any) -> str | None:
        present = [key for key in marker.keys if isinstance(value, dict) and key in value]
        return f"with {present[0]}" if present else None

    return _union(members, pick, marker.expects, message=marker.missing)


def sensor_or_placed_schema(
    cls: type, marker: SensorOrPlaced, handler: GetCoreSchemaHandler
) -> CoreSchema:
    """``cls`` as a sensor id, the mapping of its shape ``marker.placed``, or null."""
    name = marker.name
    placed = _Form(cls, _keys(cls, marker.placed), "ObjectiveLookAt", fixed={"name": name})
    members = {
        "sensor id": core_schema.no_info_after_validator_function(
            lambda sensor: cls(name=name, sensor=sensor), handler.generate_schema(_TEXT)
        ),
        "look_at mapping": _mapping(placed, handler),
        "first sensor": core_schema.no_info_after_validator_function(
            lambda _: cls(name=name), core_schema.none_schema()
        ),
    }

    def pick(value: Any) -> str | None:
        if value is None:
            return "first sensor"
        if isinstance(value, str):
            return "sensor id"
        return "look_at mapping" if isinstance(value, dict) else None

    union = _union(members, pick, "a sensor id or a mapping with look_at")
    return core_schema.with_default_schema(union, default=None, validate_default=True)


def job_path_schema(marker: JobPath, handler: GetCoreSchemaHandler) -> CoreSchema:
    """A path relative to the job file (``context["job"]``), read as an absolute path."""

    def read(value: str | None, info: core_schema.ValidationInfo) -> Path:
        job: Path = (info.context or {})["job"]
        if value is None:
            assert marker.null_means is not None
            return _resolve(job.parent, marker.null_means.format(stem=job.stem))
        path = _resolve(job.parent, value)
        marker.check(path, job.parent)
        return path

    text = handler.generate_schema(_TEXT)
    if marker.null_means is None:
        return core_schema.with_info_after_validator_function(read, text)
    nullable = core_schema.with_info_after_validator_function(
        read, core_schema.nullable_schema(text)
    )
    return core_schema.with_default_schema(nullable, default=None, validate_default=True)


def _resolve(base: Path, relative: str) -> Path:
    # abspath, not resolve(): keep the user's symlinks, so paths read as they were written.
    return Path(os.path.abspath(base / relative))


@cache
def _hints(cls: type) -> dict[str, Any]:
    # Once per class: each evaluation of the (string) annotations makes new markers, and the
    # shapes of a class compare their keys.
    return get_type_hints(cls, include_extras=True)


def _keys(cls: type, shape: str | None) -> list[_Key]:
    """The keys ``cls`` takes in ``shape`` (None: a section), in the order of its fields."""
    hints = _hints(cls)
    keys = []
    for each in dataclasses.fields(cls):
        hint = hints[each.name]
        metadata = getattr(hint, "__metadata__", ())
        places = [item for item in metadata if isinstance(item, In)]
        here = next((place for place in places if shape in place.shapes), None)
        if any(isinstance(item, Given) for item in metadata) or (places and here is None):
            continue
        keys.append(_key(each, hint, here))
    return keys


def _key(field: dataclasses.Field[Any], hint: Any, here: In | None) -> _Key:
    default = field.default
    if default is MISSING and field.default_factory is not MISSING:
        default = field.default_factory()  # a mutable default (scene_args: {})
    if here is not None:
        if here.required:
            default = MISSING
        elif here.default is not MISSING:
            default = here.default
        if here.doc is not None:
            hint = Annotated[hint, Doc(here.doc)]
    # null is accepted only where it is the default: written null means left out.
    return _Key(field.name, hint if default is None else _not_null(hint), default)


def _ordered(
    shapes: dict[str, list[_Key]], picked_by: Callable[[str], str]
) -> dict[str, list[_Key]]:
    """Each shape's keys as a base class and its subclasses would list them.

    First the keys alike in every shape, then the key that picks the shape, then its own.
    """
    first, *others = shapes.values()
    shared = {key.name for key in first if all(key in keys for keys in others)}
    return {
        shape: sorted(keys, key=lambda key: (key.name not in shared, key.name != picked_by(shape)))
        for shape, keys in shapes.items()
    }


def _mapping(form: _Form, handler: GetCoreSchemaHandler) -> CoreSchema:
    """The keys of ``form`` as a mapping, unknown keys refused first, read into its class."""
    fields = {key.name: _field(key, handler) for key in form.keys}
    names = tuple(fields)
    given = _given(form.cls)

    def build(values: dict[str, Any], info: core_schema.ValidationInfo) -> Any:
        context = info.context or {}
        loaded = {name: context[key] for name, key in given.items()}
        return form.cls(**values, **form.fixed, **loaded)

    def known(data: Any) -> Any:
        for key in data if isinstance(data, dict) else ():
            if key not in names:
                raise form.unknown(key) or Problem(
                    f"unknown key {describe(key)}{form.owner}",
                    at=(key,),
                    hint=did_you_mean(key, names, "keys"),
                )
        return data

    # A section's class gives its definition a title and description; load.py titles the rest.
    cls = form.cls if form.section else None
    typed = core_schema.typed_dict_schema(fields, cls=cls, extra_behavior="forbid")
    read = core_schema.with_info_after_validator_function(build, typed)
    return core_schema.no_info_before_validator_function(known, read, ref=form.ref)


def _given(cls: type) -> dict[str, str]:
    """The fields of ``cls`` the loader gives, and their keys in its context."""
    return {
        name: item.key
        for name, hint in _hints(cls).items()
        for item in getattr(hint, "__metadata__", ())
        if isinstance(item, Given)
    }


def _field(key: _Key, handler: GetCoreSchemaHandler) -> core_schema.TypedDictField:
    schema = handler.generate_schema(key.hint)
    # A marker may already have given the key its default (a path that null stands for).
    if key.default is not MISSING and schema["type"] != "default":
        schema = core_schema.with_default_schema(schema, default=key.default)
    return core_schema.typed_dict_field(schema, required=schema["type"] != "default")


def _union(
    members: dict[str, CoreSchema],
    pick: Callable[[Any], str | None],
    expects: str,
    *,
    field: str = "",
    choices: tuple[str, ...] = (),
    message: str = "",
) -> CoreSchema:
    """The member ``pick`` names; a value that picks none is a UNION error, told by context.

    Not a mapping (``expects``), ``field`` missing or not one of ``choices``, or ``message``.
    The members' names stand in error locations, so each has a space: no key is named so.
    """
    # pydantic takes only scalars in the context, hence the joined choices.
    context: dict[str, int | str | float] = {
        "field": field,
        "choices": ",".join(choices),
        "expects": expects,
        "message": message,
    }
    return core_schema.tagged_union_schema(
        members,
        pick,
        custom_error_type=UNION,
        custom_error_message=expects,
        custom_error_context=context,
    )


def _not_null(hint: Any) -> Any:
    """``hint`` without None among its members."""
    if get_origin(hint) is Annotated:
        return Annotated[(_not_null(hint.__origin__), *hint.__metadata__)]
    if get_origin(hint) in (Union, types.UnionType):
        return reduce(operator.or_, [arg for arg in get_args(hint) if arg is not type(None)])
    return hint


def _camel(snake: str) -> str:
    return "".join(word.capitalize() for word in snake.split("_"))
