"""``Annotated`` markers that say how a job file writes a field, without importing pydantic.

The dataclasses of :mod:`.job` are the one definition of every field; these markers add
what a job file needs besides the type: checks, descriptions, which shapes of a class take
the field. pydantic ignores metadata it does not know, so a marker is inert until pydantic
asks it (``__get_pydantic_core_schema__``, ``__get_pydantic_json_schema__``): pydantic is
loaded by then, and anything longer than a line is done in :mod:`.shapes`.

Each marker is a plain class, hashable by identity, because typing hashes an ``Annotated``
that stands in ``X | None``. ``annotated_types`` constraints (``Ge``, ``MinLen``) sit beside
these; pydantic reads those itself (but see :class:`MinItems`). The markers that need no help
from :mod:`.shapes` (:class:`Doc`, :class:`Given`, :class:`In`, :class:`Setting`) live in
:mod:`.plain_markers`, which :mod:`.shapes` reads without importing this module back.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from sensaov_cli.job.plain_markers import Doc, Given, In, Setting

__all__ = ["Doc", "Given", "In", "Setting"]  # re-exported: every marker is taken from here


class Before:
    """Check (or convert) the value as written, before its type is checked."""

    def __init__(self, check: Callable[[Any], Any]) -> None:
        self.check = check

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from pydantic_core import core_schema

        return core_schema.no_info_before_validator_function(self.check, handler(source))


class After:
    """Check (or convert) the value once its type has been checked."""

    def __init__(self, check: Callable[[Any], Any]) -> None:
        self.check = check

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from pydantic_core import core_schema

        return core_schema.no_info_after_validator_function(self.check, handler(source))


class Json:
    """What the JSON Schema must add to the type's own (or, with ``replace``, say instead)."""

    def __init__(self, schema: dict[str, Any], *, replace: bool = False) -> None:
        self.schema, self.replace = schema, replace

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> dict[str, Any]:
        return dict(self.schema) if self.replace else {**handler(schema), **self.schema}


class MinItems:
    """At least ``n`` items, counted once every item is valid.

    ``annotated_types.MinLen`` on a tuple makes pydantic count the items that passed, so one
    bad item would also read as a list too short.
    """

    def __init__(self, n: int) -> None:
        self.n = n

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from pydantic_core import PydanticKnownError, core_schema

        def check(items: tuple[Any, ...]) -> tuple[Any, ...]:
            if len(items) < self.n:
                context = {"field_type": "List", "min_length": self.n, "actual_length": len(items)}
                raise PydanticKnownError("too_short", context)
            return items

        return core_schema.no_info_after_validator_function(check, handler(source))

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> dict[str, Any]:
        return {**handler(schema), "minItems": self.n}


class JobPath:
    """A path written relative to the job file, read as an absolute path that ``check`` accepts.

    ``check(path, job_dir)`` raises :class:`~.fields.Problem`. With ``null_means``, leaving
    the key out or writing null stands for that path ("{stem}": the job file's name without
    its suffix), unchecked.
    """

    def __init__(self, check: Callable[[Path, Path], None], null_means: str | None = None):
        self.check, self.null_means = check, null_means

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from sensaov_cli.job import shapes

        return shapes.job_path_schema(self, handler)


class Section:
    """Base of a class that a job file writes as one mapping of its fields."""

    @classmethod
    def __get_pydantic_core_schema__(cls, source: Any, handler: Any) -> Any:
        from sensaov_cli.job import shapes

        return shapes.section_schema(cls, handler)


class Tagged:
    """The class is written in one shape per value of its ``field`` ("type: python").

    ``expects`` says what an item must be; each shape is titled by its value and ``noun``.
    """

    def __init__(self, field: str, expects: str, noun: str) -> None:
        self.field, self.expects, self.noun = field, expects, noun

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from sensaov_cli.job import shapes

        return shapes.tagged_schema(source, self, handler)


class TaggedByKey:
    """The class is written in the shape named by the first of ``keys`` present in it.

    ``owners`` name each shape in an unknown-key error (" for a sensor camera"); ``missing``
    says that no key is present, ``clash`` (with "{}" for the key) that a second one is.
    ``expects`` says what an item must be; each shape is titled by its key and ``noun``.
    """

    def __init__(
        self,
        keys: tuple[str, ...],
        *,
        owners: tuple[str, ...],
        expects: str,
        missing: str,
        clash: str,
        noun: str,
    ) -> None:
        self.keys, self.owners, self.noun = keys, owners, noun
        self.expects, self.missing, self.clash = expects, missing, clash

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from sensaov_cli.job import shapes

        return shapes.tagged_by_key_schema(source, self, handler)


class SensorOrPlaced:
    """A camera written as a sensor id, as the mapping of its shape ``placed``, or as null.

    The camera is named ``name``; null (or no key) is the scene's first sensor.
    """

    def __init__(self, placed: str, name: str) -> None:
        self.placed, self.name = placed, name

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from sensaov_cli.job import shapes

        return shapes.sensor_or_placed_schema(source, self, handler)
