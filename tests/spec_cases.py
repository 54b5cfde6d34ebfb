"""Malformed job files and where their error must point; shared by test_spec and test_cli_errors.

Each case is a whole job file, so the expected line can be read off the text. ``key_path`` is
the full key path the error must name ("" for file-level problems), ``line`` the line it must
name (None when the file has no line to point at), ``says`` a fragment of the message or hint.
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass
from pathlib import Path

import pytest

FIXTURE_FILES = ("scene.xml", "target.exr", "mask.exr")


@dataclass(frozen=True)
class SpecCase:
    id: str
    text: str
    key_path: str
    line: int | None
    says: str


def write_fixture(root: Path, text: str, name: str = "job.yaml") -> Path:
    """A job file ``name`` with ``text`` beside a dummy scene, target, mask and module dir."""
    root.mkdir(parents=True, exist_ok=True)
    for file_name in FIXTURE_FILES:
        (root / file_name).write_text("dummy\n")
    (root / "pydir").mkdir(exist_ok=True)
    job = root / name
    job.write_text(textwrap.dedent(text))
    return job


def expected_where(job: str, case: SpecCase) -> str:
    """The start of the error line: ``<job>:<line>: <key path>``."""
    where = job if case.line is None else f"{job}:{case.line}"
    return f"{where}: {case.key_path}" if case.key_path else where


HEAD = "version: 1\nscene: scene.xml\noutput: out\n"
ONE_OBJECTIVE = "objectives:\n  - name: luma\n    type: mean_luminance\n"

CASES = [
    SpecCase(
        "unknown top-level key",
        HEAD + "objectivs:\n  - name: a\n",
        "objectivs",
        4,
        "did you mean 'objectives'?",
    ),
    SpecCase(
        "unknown nested key",
        HEAD + "render:\n  spp: 4\n  max_dept: 3\n" + ONE_OBJECTIVE,
        "render.max_dept",
        6,
        "did you mean 'max_depth'?",
    ),
    SpecCase(
        "spp is a word",
        HEAD + "render:\n  spp: many\n" + ONE_OBJECTIVE,
        "render.spp",
        5,
        "must be an integer, got 'many'",
    ),
    SpecCase(
        "spp is a quoted number",
        HEAD + 'render:\n  spp: "64"\n' + ONE_OBJECTIVE,
        "render.spp",
        5,
        "without quotes",
    ),
    SpecCase(
        "spp is a boolean",
        HEAD + "render:\n  spp: true\n" + ONE_OBJECTIVE,
        "render.spp",
        5,
        "got true",
    ),
    SpecCase(
        "spp is zero",
        HEAD + "render: {spp: 0}\n" + ONE_OBJECTIVE,
        "render.spp",
        4,
        "greater than or equal to 1",
    ),
    SpecCase(
        "batches is a word",
        HEAD + "render:\n  spp: 8\n  batches: many\n" + ONE_OBJECTIVE,
        "render.batches",
        6,
        "must be 'auto' or an integer from 1 to 1024, got 'many'",
    ),
    SpecCase(
        "batches is zero",
        HEAD + "render:\n  batches: 0\n" + ONE_OBJECTIVE,
        "render.batches",
        5,
        "must be 'auto' or an integer",
    ),
    SpecCase(
        "batches exceed spp",
        HEAD + "render:\n  spp: 4\n  batches: 8\n" + ONE_OBJECTIVE,
        "render.batches",
        6,
        "cannot exceed spp",
    ),
    SpecCase(
        "until has an unknown key",
        HEAD + "render:\n  until: {resolved: 5, max_spp: 512, budget: 3}\n" + ONE_OBJECTIVE,
        "render.until.budget",
        5,
        "unknown key 'budget'",
    ),
    SpecCase(
        "until misses max_spp",
        HEAD + "render:\n  until:\n    resolved: 5\n" + ONE_OBJECTIVE,
        "render.until.max_spp",
        5,
        "missing required key",
    ),
    SpecCase(
        "until resolved is a word",
        HEAD + "render:\n  until:\n    resolved: five\n    max_spp: 512\n" + ONE_OBJECTIVE,
        "render.until.resolved",
        6,
        "must be an integer, got 'five'",
    ),
    SpecCase(
        "until max_spp below spp",
        HEAD + "render:\n  spp: 64\n  until:\n    resolved: 5\n    max_spp: 32\n" + ONE_OBJECTIVE,
        "render.until.max_spp",
        8,
        "cannot be less than spp",
    ),
    SpecCase(
        "max_depth is zero",
        HEAD + "render:\n  max_depth: 0\n" + ONE_OBJECTIVE,
        "render.max_depth",
        5,
        "-1 (unbounded) or at least 1",
    ),
    SpecCase(
        "resolution has three items",
        HEAD + "render:\n  resolution: [64, 48, 2]\n" + ONE_OBJECTIVE,
        "render.resolution",
        5,
        "list of 2 integers",
    ),
    SpecCase(
        "region out of range",
        HEAD + "objectives:\n  - name: c\n    type: region_luminance\n"
        "    region: [0.1, 0.1, 1.5, 0.9]\n",
        "objectives[0].region[2]",
        7,
        "less than or equal to 1",
    ),
    SpecCase(
        "region x0 >= x1",
        HEAD + "objectives:\n  - name: c\n    type: region_luminance\n"
        "    region: [0.6, 0.1, 0.4, 0.9]\n",
        "objectives[0].region",
        7,
        "x0 (0.6) must be less than x1 (0.4)",
    ),
    SpecCase(
        "region and mask",
        HEAD + "objectives:\n  - name: c\n    type: region_luminance\n"
        "    region: [0, 0, 1, 1]\n    mask: mask.exr\n",
        "objectives[0].mask",
        8,
        "exactly one of region or mask",
    ),
    SpecCase(
        "missing scene file",
        "version: 1\nscene: nowhere/scene.xml\n" + ONE_OBJECTIVE,
        "scene",
        2,
        "file not found",
    ),
    SpecCase(
        "scene key missing", "version: 1\n" + ONE_OBJECTIVE, "scene", 1, "missing required key"
    ),
    SpecCase(
        "missing target file",
        HEAD + "objectives:\n  - name: m\n    type: l2_to_target\n    target: missing.exr\n",
        "objectives[0].target",
        7,
        "missing.exr",
    ),
    SpecCase(
        "python path is not a directory",
        HEAD + "objectives:\n  - name: p\n    type: python\n"
        "    function: mod:fn\n    path: scene.xml\n",
        "objectives[0].path",
        8,
        "not a directory",
    ),
    SpecCase(
        "bad function reference",
        HEAD + "objectives:\n  - name: p\n    type: python\n    function: mod.fn\n",
        "objectives[0].function",
        7,
        "'module:function'",
    ),
    SpecCase(
        "duplicate objective names",
        HEAD + ONE_OBJECTIVE + "  - name: luma\n    type: mean_luminance\n",
        "objectives[1].name",
        7,
        "already used by objectives[0]",
    ),
    SpecCase(
        "duplicate YAML key",
        HEAD + "render:\n  spp: 4\n  seed: 1\n  spp: 8\n" + ONE_OBJECTIVE,
        "render.spp",
        7,
        "duplicate key (first given on line 5)",
    ),
    SpecCase(
        "version 2", "version: 2\nscene: scene.xml\n" + ONE_OBJECTIVE, "version", 1, "versions: 1"
    ),
    SpecCase(
        "version as a string",
        "version: '1'\nscene: scene.xml\n" + ONE_OBJECTIVE,
        "version",
        1,
        "must be an integer, got '1'",
    ),
    SpecCase(
        "YAML syntax error",
        HEAD + "objectives:\n  - name: a\n     type: mean_luminance\n",
        "",
        6,
        "invalid YAML",
    ),
    SpecCase(
        "empty objectives list", HEAD + "objectives: []\n", "objectives", 4, "at least 1 item"
    ),
    SpecCase(
        "unknown objective type",
        HEAD + "objectives:\n  - name: a\n    type: mean_lum\n",
        "objectives[0].type",
        6,
        "did you mean 'mean_luminance'?",
    ),
    SpecCase(
        "objective name pattern",
        HEAD + "objectives:\n  - name: 2fast\n    type: mean_luminance\n",
        "objectives[0].name",
        5,
        "starting with a letter",
    ),
    SpecCase(
        "select channel without glob",
        HEAD + ONE_OBJECTIVE + "channels:\n  - name: pick\n    kind: select\n",
        "channels[0].select",
        8,
        "missing required key",
    ),
    SpecCase(
        "select glob on an object channel",
        HEAD + ONE_OBJECTIVE + "channels:\n  - name: obj\n    kind: object\n    select: '*'\n",
        "channels[0].select",
        10,
        "unknown key 'select' for kind object",
    ),
    SpecCase(
        "region on mean_luminance",
        HEAD + ONE_OBJECTIVE + "    region: [0, 0, 1, 1]\n",
        "objectives[0].region",
        7,
        "unknown key 'region' for type mean_luminance",
    ),
    SpecCase(
        "camera with look_at and sensor",
        HEAD + ONE_OBJECTIVE + "inspection_cameras:\n  - name: top\n"
        "    look_at: {origin: [0, 3, 3], target: [0, 0, 0], up: [0, 1, 0]}\n"
        "    sensor: sensor2\n",
        "inspection_cameras[0].sensor",
        10,
        "only one of",
    ),
    SpecCase(
        "camera with no kind",
        HEAD + ONE_OBJECTIVE + "inspection_cameras:\n  - name: top\n",
        "inspection_cameras[0]",
        8,
        "needs one of look_at, sensor or objective",
    ),
    SpecCase(
        "look_at origin equals target",
        HEAD + ONE_OBJECTIVE + "inspection_cameras:\n  - name: top\n"
        "    look_at: {origin: [1, 2, 3], target: [1, 2, 3], up: [0, 1, 0]}\n",
        "inspection_cameras[0].look_at.target",
        9,
        "must differ from origin",
    ),
    SpecCase(
        "fov of 180 degrees",
        HEAD + ONE_OBJECTIVE + "inspection_cameras:\n  - name: top\n"
        "    look_at: {origin: [0, 3, 3], target: [0, 0, 0], up: [0, 1, 0]}\n"
        "    fov: 180\n",
        "inspection_cameras[0].fov",
        10,
        "less than 180",
    ),
    SpecCase(
        "objective camera is a number",
        HEAD + "objective_camera: 3\n" + ONE_OBJECTIVE,
        "objective_camera",
        4,
        "must be a sensor id or a mapping with look_at",
    ),
    SpecCase(
        "bad variant",
        HEAD + "variant: cuda_rgb\n" + ONE_OBJECTIVE,
        "variant",
        4,
        "did you mean 'cuda_ad_rgb'?",
    ),
    SpecCase("empty file", "", "", None, "empty"),
    SpecCase("comments only", "# nothing here\n", "", None, "empty"),
    SpecCase(
        "top-level list",
        "- version: 1\n- scene: scene.xml\n",
        "",
        1,
        "must be a mapping of keys, not a list",
    ),
    SpecCase(
        "python tag refused",
        HEAD + "render: !!python/name:os.system\n" + ONE_OBJECTIVE,
        "",
        4,
        "invalid YAML",
    ),
]

CASE_PARAMS = [pytest.param(case, id=case.id) for case in CASES]
