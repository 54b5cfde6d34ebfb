"""How an output was made: the one place that says which tool and command wrote a file.

``sensaov run`` and ``sensaov project`` both start their provenance with :func:`made_by` and
store it with :func:`provenance_attributes`, so every file reads the same way.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from sensaov_cli import __version__

PROVENANCE_ATTRIBUTE = "sensaov/provenance"


def made_by(command: str) -> dict[str, str]:
    """The fields every provenance record starts with: the tool, its version, the command."""
    return {"tool": "sensaov", "tool_version": __version__, "command": command}


def header_provenance(header: Mapping[str, Any]) -> dict[str, Any] | None:
    """The provenance an EXR header carries, or None where it holds none sensaov wrote."""
    try:
        recorded = json.loads(header[PROVENANCE_ATTRIBUTE])
    except (KeyError, TypeError, ValueError):
        return None
    return recorded if isinstance(recorded, dict) else None


def provenance_attributes(provenance: dict[str, Any]) -> dict[str, str]:
    """The provenance as the EXR header attribute that carries it (sorted keys, stable text)."""
    return {PROVENANCE_ATTRIBUTE: json.dumps(provenance, sort_keys=True)}
