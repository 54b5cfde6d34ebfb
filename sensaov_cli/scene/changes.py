"""What preparing a scene changes in it, and what it finds Mitsuba would refuse, gathered.

Changes are listed by ``sensaov params`` and in a buffer's provenance; refusals are gathered
over the whole scene (every missing file, every unsupported plugin or property) and reported
together, so that a user fixes them in one round, before Mitsuba starts.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

from sensaov_cli.errors import SceneError

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
