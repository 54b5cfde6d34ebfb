"""How a job file writes a field and words its mistakes: ``Annotated`` markers, their schemas.

The markers add to a field of :mod:`.spec` what a job file needs besides the type: checks,
descriptions, which shapes of a class take the field. A marker is inert until pydantic asks it
(``__get_pydantic_core_schema__``, ``__get_pydantic_json_schema__``), and pydantic is imported
only inside those hooks, so :mod:`.spec` loads none. Each marker is a plain class, hashable by
identity, because typing hashes an ``Annotated`` that stands in ``X | None``.

A section (render, parameters, look_at, the job) is one mapping of its fields, bar those the
loader gives. A class written in several shapes is a tagged union of such mappings, each
taking the fields marked ``In`` that shape and the fields marked nowhere. Every mapping refuses
an unknown key before it looks at any value, and builds the dataclass through its
``__init__``, so ``__post_init__`` checks hold for a job file too.
"""

from __future__ import annotations

import dataclasses
import difflib
import operator
import os
import types
from collections.abc import Callable, Sequence
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

if TYPE_CHECKING:  # pydantic is imported where it is called: spec.py loads none of it
    from pydantic import GetCoreSchemaHandler
    from pydantic.json_schema import JsonSchemaValue
    from pydantic_core import CoreSchema, core_schema


class Problem(ValueError):
    """A mistake in a job file, in our own words; ``at`` (YAML keys, list indices) extends the
    key path of the value. pydantic reports it as a ``value_error`` that carries it."""

    def __init__(self, message: str, *, at: tuple[Any, ...] = (), hint: str | None = None):
        super().__init__(message)
        self.message, self.at, self.hint = message, at, hint


def describe(value: Any) -> str:
    """A short YAML-flavoured rendering of a user's value for an error message."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "null"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return repr(value if len(value) <= 40 else value[:37] + "...")
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "a mapping"
    return f"a {type(value).__name__}"


def did_you_mean(word: object, choices: Sequence[str]) -> str | None:
    """'did you mean X?' when ``word`` is likely a typo of one of ``choices``."""
    close = difflib.get_close_matches(str(word), choices, n=1, cutoff=0.6)
    return f"did you mean '{close[0]}'?" if close else None


# The error type of a value that picks no member of a union; its context says why.
UNION = "sensaov_union"
UNION_MEMBERS: set[str] = set()  # every union's members' names, which stand in error locations


class JobFilePath:
    """Not a key of the job file: the job file's own path, ``context["job"]`` of the validation."""


class In:
    """The field is a key of these shapes of its class only (objective types, camera kinds);
    there it may be ``required``, or have a ``default`` and a ``doc`` of its own."""

    def __init__(
        self, *shapes: str, required: bool = False, default: Any = MISSING, doc: str | None = None
    ) -> None:
        self.shapes, self.required, self.default, self.doc = shapes, required, default, doc


class Setting:
    """Keys of pydantic's core schema of a scalar: ``strict``, ``pattern``, ``allow_inf_nan``."""

    def __init__(self, **settings: Any) -> None:
        self.settings = settings

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        return {**handler(source), **self.settings}


STRICT = Setting(strict=True)
Text = Annotated[str, STRICT, MinLen(1)]  # a tag, a sensor id, a path


class After:
    """Check (or convert) the value once its type has been checked."""

    def __init__(self, check: Callable[[Any], Any]) -> None:
        self.check = check

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from pydantic_core import core_schema

        if isinstance(self, Before):
            return core_schema.no_info_before_validator_function(self.check, handler(source))
        return core_schema.no_info_after_validator_function(self.check, handler(source))


class Before(After):
    """Check (or convert) the value as written, before its type is checked."""


class Json:
    """What the JSON Schema must add to the type's own (or, with ``replace``, say instead)."""

    def __init__(self, schema: JsonSchemaValue, *, replace: bool = False) -> None:
        self.schema, self.replace = schema, replace

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> JsonSchemaValue:
        return dict(self.schema) if self.replace else {**handler(schema), **self.schema}


class Doc(Json):
    """A field's description in the JSON Schema."""

    def __init__(self, text: str) -> None:
        super().__init__({"description": text})


class NonEmpty(After):
    """At least one item, counted once every item is valid (``annotated_types.MinLen`` on a
    tuple counts the items that passed, so one bad item would also read as a list too short)."""

    def __init__(self) -> None:
        def check(items: tuple[Any, ...]) -> tuple[Any, ...]:
            if not items:
                raise Problem("must have at least 1 item, got 0")
            return items

        super().__init__(check)

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> JsonSchemaValue:
        return {**handler(schema), "minItems": 1}


class JobPath:
    """A path written relative to the job file (``context["job"]`` of the validation), read as
    an absolute path that ``check(path, job_dir)`` accepts. With ``null_means``, leaving the key
    out or writing null stands for that path ("{stem}": the job file's stem), unchecked."""

    def __init__(self, check: Callable[[Path, Path], None], null_means: str | None = None):
        self.check, self.null_means = check, null_means

    def __get_pydantic_core_schema__(self, source: Any, handler: GetCoreSchemaHandler) -> Any:
        from pydantic_core import core_schema

        def read(value: str | None, info: core_schema.ValidationInfo) -> Path:
            job: Path = (info.context or {})["job"]
            if value is None:
                assert self.null_means is not None
                return _resolve(job.parent, self.null_means.format(stem=job.stem))
            path = _resolve(job.parent, value)
            self.check(path, job.parent)
            return path

        text = handler.generate_schema(Text)
        if self.null_means is None:
            return core_schema.with_info_after_validator_function(read, text)
        nullable = core_schema.with_info_after_validator_function(
            read, core_schema.nullable_schema(text)
        )
        return core_schema.with_default_schema(nullable, default=None, validate_default=True)


class Section:
    """Base of a class that a job file writes as one mapping of its fields."""

    @classmethod
    def __get_pydantic_core_schema__(cls, source: Any, handler: GetCoreSchemaHandler) -> Any:
        return _mapping(_Form(cls, _keys(cls, None), cls.__name__), handler)


class Tagged:
    """The class is written in one shape per value of its ``field`` ("type: python"), each
    titled by its value and ``noun``."""

    def __init__(self, field: str, noun: str) -> None:
        self.field, self.noun = field, noun

    def __get_pydantic_core_schema__(self, cls: type, handler: GetCoreSchemaHandler) -> Any:
        tag = self.field
        values: tuple[str, ...] = get_args(get_type_hints(cls)[tag])

        def tagged(key: _Key, value: str) -> _Key:
            # Within its shape the tag has the one value.
            return _Key(tag, Literal[value], MISSING) if key.name == tag else key

        shapes = {value: [tagged(key, value) for key in _keys(cls, value)] for value in values}
        members = {}
        for value, keys in _ordered(shapes, tag).items():
            form = _Form(cls, keys, _camel(value) + self.noun, owner=f" for {tag} {value}")
            members[f"{tag}: {value}"] = _mapping(form, handler)

        def pick(value: Any) -> str | None:
            chosen = value.get(tag) if isinstance(value, dict) else None
            return f"{tag}: {chosen}" if isinstance(chosen, str) and chosen in values else None

        expects = f"a mapping with name and {tag}"
        return _union(members, pick, expects, field=tag, choices=",".join(values))


@dataclass(frozen=True, eq=False)
class TaggedByKey:
    """The class is written in the shape named by the first of ``keys`` present in it.

    ``owners`` name each shape in an unknown-key error (" for a sensor camera"); ``missing``
    says that no key is present, ``clash`` (with "{}" for the key) that a second one is.
    ``expects`` says what an item must be; each shape is titled by its key and ``noun``.
    """

    keys: tuple[str, ...]
    owners: tuple[str, ...]
    expects: str
    missing: str
    clash: str
    noun: str

    def __get_pydantic_core_schema__(self, cls: type, handler: GetCoreSchemaHandler) -> Any:
        shapes = _ordered({key: _keys(cls, key) for key in self.keys}, None)

        def clash(key: Any) -> Problem | None:
            return Problem(self.clash.format(key), at=(key,)) if key in self.keys else None

        members = {}
        for (key, keys), owner in zip(shapes.items(), self.owners, strict=True):
            form = _Form(cls, keys, _camel(key) + self.noun, owner=owner, unknown=clash)
            members[f"with {key}"] = _mapping(form, handler)

        def pick(value: Any) -> str | None:
            present = [key for key in self.keys if isinstance(value, dict) and key in value]
            return f"with {present[0]}" if present else None

        return _union(members, pick, self.expects, message=self.missing)


class SensorOrPlaced:
    """A camera named ``name``, written as a sensor id, as the mapping of its shape ``placed``,
    or as null (or no key): the scene's first sensor."""

    def __init__(self, placed: str, name: str) -> None:
        self.placed, self.name = placed, name

    def __get_pydantic_core_schema__(self, cls: type, handler: GetCoreSchemaHandler) -> Any:
        from pydantic_core import core_schema

        placed = _Form(cls, _keys(cls, self.placed), "ObjectiveLookAt", fixed={"name": self.name})
        members = {
            "sensor id": core_schema.no_info_after_validator_function(
                lambda sensor: cls(name=self.name, sensor=sensor), handler.generate_schema(Text)
            ),
            "look_at mapping": _mapping(placed, handler),
            "first sensor": core_schema.no_info_after_validator_function(
                lambda _: cls(name=self.name), core_schema.none_schema()
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


# --- the schemas' parts --------------------------------------------------------------------


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
    fixed: dict[str, str] = field(default_factory=dict)  # fields the shape does not write
    unknown: Callable[[Any], Problem | None] = lambda key: None  # a better word for a key


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
    keys = []
    for each in dataclasses.fields(cls):
        hint = _hints(cls)[each.name]
        markers = getattr(hint, "__metadata__", ())
        places = [item for item in markers if isinstance(item, In)]
        here = next((place for place in places if shape in place.shapes), None)
        if JobFilePath in markers or (places and here is None):
            continue
        default = each.default
        if default is MISSING and each.default_factory is not MISSING:
            default = each.default_factory()  # a mutable default (scene_args: {})
        if here is not None:
            if here.required:
                default = MISSING
            elif here.default is not MISSING:
                default = here.default
            if here.doc is not None:
                hint = Annotated[hint, Doc(here.doc)]
        # null is accepted only where it is the default: written null means left out.
        keys.append(_Key(each.name, hint if default is None else _not_null(hint), default))
    return keys


def _ordered(shapes: dict[str, list[_Key]], tag: str | None) -> dict[str, list[_Key]]:
    """Each shape's keys as a base class and its subclasses would list them: first the keys
    alike in every shape, then the key that picks the shape (``tag``, else the shape's name)."""
    first, *others = shapes.values()
    shared = {key.name for key in first if all(key in keys for keys in others)}
    return {
        shape: sorted(keys, key=lambda key: (key.name not in shared, key.name != (tag or shape)))
        for shape, keys in shapes.items()
    }


def _mapping(form: _Form, handler: GetCoreSchemaHandler) -> CoreSchema:
    """The keys of ``form`` as a mapping, unknown keys refused first, read into its class."""
    from pydantic_core import core_schema

    fields = {key.name: _field(key, handler) for key in form.keys}
    names = tuple(fields)
    hints = _hints(form.cls)
    given = [
        name for name, hint in hints.items() if JobFilePath in getattr(hint, "__metadata__", ())
    ]

    def build(values: dict[str, Any], info: core_schema.ValidationInfo) -> Any:
        loaded = {name: (info.context or {})["job"] for name in given}
        return form.cls(**values, **form.fixed, **loaded)

    def known(data: Any) -> Any:
        for key in data if isinstance(data, dict) else ():
            if key not in names:
                raise form.unknown(key) or Problem(
                    f"unknown key {describe(key)}{form.owner}",
                    at=(key,),
                    hint=did_you_mean(key, names) or "valid keys: " + ", ".join(names),
                )
        return data

    # A section, named after its class, has the class's title and docstring; load.py titles others.
    cls = form.cls if form.ref == form.cls.__name__ else None
    typed = core_schema.typed_dict_schema(fields, cls=cls, extra_behavior="forbid")
    read = core_schema.with_info_after_validator_function(build, typed)
    return core_schema.no_info_before_validator_function(known, read, ref=form.ref)


def _field(key: _Key, handler: GetCoreSchemaHandler) -> core_schema.TypedDictField:
    from pydantic_core import core_schema

    schema = handler.generate_schema(key.hint)
    # A marker may already have given the key its default (a path that null stands for).
    if key.default is not MISSING and schema["type"] != "default":
        schema = core_schema.with_default_schema(schema, default=key.default)
    return core_schema.typed_dict_field(schema, required=schema["type"] != "default")


def _union(
    members: dict[str, CoreSchema], pick: Callable[[Any], str | None], expects: str, **why: str
) -> CoreSchema:
    """The member ``pick`` names; a value that picks none is a UNION error whose context says
    why: not a mapping (``expects``), the tag ``field`` missing or not one of ``choices`` (joined
    by commas: pydantic takes only scalars in a context), or ``message``. The members' names
    stand in error locations, so each has a space: no key is named so."""
    from pydantic_core import core_schema

    UNION_MEMBERS.update(members)
    return core_schema.tagged_union_schema(
        members,
        pick,
        custom_error_type=UNION,
        custom_error_message=expects,
        custom_error_context={**why, "expects": expects},
    )


def _not_null(hint: Any) -> Any:
    if get_origin(hint) is Annotated:
        return Annotated[(_not_null(hint.__origin__), *hint.__metadata__)]
    if get_origin(hint) in (Union, types.UnionType):
        return reduce(operator.or_, [arg for arg in get_args(hint) if arg is not type(None)])
    return hint


def _camel(snake: str) -> str:
    return "".join(word.capitalize() for word in snake.split("_"))
