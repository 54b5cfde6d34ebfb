"""How each bitmap texture is looked up (filter, wrap, ``to_uv``), and which objects lack UVs.

A texel field is painted through the same lookup Mitsuba's ``bitmap`` plugin performs, so the
project stage needs the lookup's settings as plain data. ``to_uv`` is a traversed parameter;
``filter_type`` and ``wrap_mode`` are not exposed by the plugin's Python binding, so they are
read from the prepared scene (``PreparedScene.bitmap_options``) and confirmed by probing the
texture's own lookup.
"""

from __future__ import annotations

import re
from types import ModuleType
from typing import Any

from sensaov_cli.scene.prepare import DEFAULT_FILTER, DEFAULT_WRAP

PROBES, PROBE_SEED = 256, 9


def texture_probes(
    mi: ModuleType, params: Any, keys: tuple[str, ...], options: dict[str, tuple[str, str, str]]
) -> dict[str, dict[str, Any]]:
    """Per texture ``data`` key, plain data to pin its lookup down: the scene XML's settings
    (``filter``, ``wrap``, ``note``), ``to_uv`` (3x3 rows), the texels, and the texture's own
    values at ``PROBES`` random UVs (``uv``, ``values``), which the caller matches against
    every filter and wrap mode: a file used with several settings cannot fool that."""
    import drjit as dr
    import numpy as np

    rng = np.random.default_rng(PROBE_SEED)
    result = {}
    for key in keys:
        node = params.properties[key][2]
        match = re.search(r'name = "([^"]*)"', str(node))
        found = options.get(match.group(1) if match else "", None)
        filter_type, wrap, note = found or (DEFAULT_FILTER, DEFAULT_WRAP, "")
        to_uv_key = key[: -len("data")] + "to_uv"
        matrix = np.eye(3)
        if to_uv_key in params.keys():
            matrix = np.array(params[to_uv_key].matrix, dtype=np.float64).reshape(3, 3)
        texels = np.array(params[key], dtype=np.float64)
        uv = rng.uniform(-1.5, 2.5, (PROBES, 2))
        with dr.suspend_grad():
            si = dr.zeros(mi.SurfaceInteraction3f, PROBES)
            si.uv = mi.Point2f(uv[:, 0], uv[:, 1])
            if texels.shape[2] == 1:
                values = np.array(node.eval_1(si), dtype=np.float64)[:, None]
            else:
                values = np.array(node.eval(si), dtype=np.float64).T
        result[key] = {
            "filter": filter_type,
            "wrap": wrap,
            "note": note,
            "to_uv": matrix.tolist(),
            "texels": texels,
            "uv": uv,
            "values": values,
        }
    return result


def objects_without_uv(mi: ModuleType, scene: Any, objects: tuple[str, ...]) -> tuple[str, ...]:
    """Meshes without texture coordinates: Mitsuba reads texel (0, 0) wherever they are hit."""
    missing = []
    for number, shape in enumerate(scene.shapes()):
        name = shape.id() or f"shape_{number}"
        if name in objects and shape.is_mesh() and not shape.has_vertex_texcoords():
            missing.append(name)
    return tuple(sorted(missing))
