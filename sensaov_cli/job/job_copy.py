"""A viewpoint saved from ``sensaov view``: a job's inspection camera as YAML, or a job copy.

The camera entry is what ``inspection_cameras`` takes (a ``look_at`` camera), so the same view
can be projected on a farm. The copy is the job as written (read back as ``yaml.safe_load``
reads it, so its comments are not kept) with the cameras appended and every path rewritten
relative to where the copy lies, so that it names the same scene, files and output folder.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from sensaov_cli.job.fields import NAME_PATTERN
from sensaov_cli.job.spec import CameraSpec, JobSpec

RESERVED_NAMES = ("primal", "buffer", "objective")


def camera_entry(camera: CameraSpec) -> dict[str, Any]:
    """The mapping a job's ``inspection_cameras`` list takes for a ``look_at`` camera."""
    assert camera.look_at is not None and camera.resolution is not None
    look = camera.look_at
    return {
        "name": camera.name,
        "look_at": {
            "origin": [_round(v) for v in look.origin],
            "target": [_round(v) for v in look.target],
            "up": [_round(v) for v in look.up],
        },
        "fov": _round(camera.fov),
        "resolution": list(camera.resolution),
        "vis_spp": camera.vis_spp,
    }


def camera_yaml(camera: CameraSpec) -> str:
    """The camera as one YAML list item, ready to paste under ``inspection_cameras:``."""
    return yaml.safe_dump([camera_entry(camera)], sort_keys=False, default_flow_style=None)


def check_camera_name(name: str, taken: Sequence[str]) -> str | None:
    """Why ``name`` cannot name a new inspection camera, or None when it can."""
    if not re.fullmatch(NAME_PATTERN, name):
        return f"camera name {name!r} must be a letter then up to 31 letters, digits or _"
    if name in RESERVED_NAMES:
        return f"camera name {name!r} is reserved"
    if name in taken:
        return f"the job already has an inspection camera named {name!r}"
    return None


def job_copy_text(
    job: JobSpec, base: Path, cameras: Sequence[CameraSpec], copy: Path, buffer: Path
) -> str:
    """The job file ``base`` (the job itself, or an earlier copy of it) with ``cameras``
    appended, its paths rewritten for a file at ``copy``; ``buffer`` is named in its header."""
    data = yaml.safe_load(base.read_text())
    folder = copy.parent
    data["scene"] = _relative(job.scene, folder)
    data["output"] = _relative(job.output, folder)
    for raw, objective in zip(data.get("objectives") or [], job.objectives, strict=False):
        for field in ("mask", "target", "path"):
            value = getattr(objective, field)
            if isinstance(raw, dict) and value is not None:
                raw[field] = _relative(value, folder)
    listed = data.get("inspection_cameras") or []
    data["inspection_cameras"] = [*listed, *(camera_entry(c) for c in cameras)]
    default = os.path.abspath(buffer) == os.path.abspath(job.output / "buffer.npz")
    option = "" if default else f" --buffer {os.path.abspath(buffer)}"
    head = (
        f"# {job.path.name} with cameras saved by 'sensaov view' (comments of the original are "
        "not kept;\n# paths are relative to this file). Project them with:\n"
        f"#   sensaov project {copy.name}{option}\n"
    )
    return head + yaml.safe_dump(data, sort_keys=False, default_flow_style=None)


def camera_names(path: Path) -> tuple[str, ...]:
    """The names of the inspection cameras a job file lists (read as written)."""
    data = yaml.safe_load(path.read_text()) or {}
    listed = data.get("inspection_cameras") or []
    return tuple(str(c.get("name")) for c in listed if isinstance(c, dict))


def _relative(path: Path, folder: Path) -> str:
    return os.path.relpath(os.path.abspath(path), os.path.abspath(folder))


def _round(value: float) -> float:
    """Six significant digits: a camera moved by a mouse needs no more, and reads better."""
    return float(f"{value:.6g}")
