"""Names from scenes and buffers are data, never paths: the file-name token each one becomes.

An objective's name, a parameter type or an object id read from a stranger's buffer may hold
``/``, ``..``, control characters, 300 characters or any Unicode. A file name is built only from
:func:`file_token`'s output: ASCII letters, digits, ``_``, ``-`` and inner ``.``, at most
:data:`MAX_TOKEN` characters, never empty, never ``.`` or ``..``, never hidden. A name that
needed changing gets a short hash of the original, so two names never share a file; the
original is kept in the file's metadata by the writer.
"""

from __future__ import annotations

import hashlib
import re

MAX_TOKEN = 64  # with a camera and a pass name, a preview's path stays far below NAME_MAX
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")
_HASH_CHARS = 8


def file_token(name: str) -> str:
    """``name`` itself when it is a safe file-name token already, else a sanitised stand-in."""
    if _is_safe(name):
        return name
    digest = hashlib.sha256(name.encode("utf-8", "surrogatepass")).hexdigest()[:_HASH_CHARS]
    stem = _UNSAFE.sub("_", name).strip("._-")[: MAX_TOKEN - _HASH_CHARS - 1]
    return f"{stem}_{digest}" if stem else f"name_{digest}"


def _is_safe(name: str) -> bool:
    return (
        0 < len(name) <= MAX_TOKEN
        and _UNSAFE.search(name) is None
        and not name.startswith((".", "-"))
        and ".." not in name
    )
