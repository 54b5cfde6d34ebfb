"""The integrator that differentiates the image the scene itself renders (pure XML).

sensaov replaces the scene's integrator by a path-replay one (``prb``, or ``prbvolpath`` where
the scene renders participating media), because Mitsuba's ``path`` needs memory that grows with
spp under AD. The replay renders what the scene renders: a wrapper is unwrapped, the depth is
the scene's (``direct`` is prb at depth 2) unless the job sets ``render.max_depth``, and
``hide_emitters`` and ``rr_depth`` are kept. An integrator that renders something else
(``depth``, ``aov`` alone, 0.5's ``ao``) is replaced all the same, and said to alter the image.
Where the job changes the depth, the plan carries the replay at the scene's own depth, so that
the effect can be measured by rendering both at one seed (``render/adjoint.py``).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass

from sensaov_cli.errors import SceneError
from sensaov_cli.scene.naming import child_value
from sensaov_cli.scene.source import Change, where

# Integrators whose image is their nested integrator's.
_WRAPPERS = frozenset({"moment", "stokes", "aov", "adaptive", "irrcache", "multichannel"})
_VOLUMETRIC = frozenset({"volpath", "volpathmis", "prbvolpath", "volpath_simple"})
# The same light transport as a path tracer, in Mitsuba 3.9.1 (default depth: -1, or prb's 6).
_SAME = {"path": -1, "ptracer": -1, "volpath": -1, "volpathmis": -1, "prbvolpath": 6}
_SAME |= dict.fromkeys(("prb", "prb_basic", "prb_projective", "direct_projective"), 6)
# Mitsuba 0.5/0.6 estimators of full light transport with no counterpart in Mitsuba 3; all but
# path and direct render media where the scene has them.
_LEGACY = frozenset(
    {"guided_path", "bdpt", "pssmlt", "mlt", "erpt", "photonmapper", "ppm", "sppm", "vpl",
     "volpath_simple"}
)  # fmt: skip
KEPT_SETTINGS = ("hide_emitters", "rr_depth")
UNBOUNDED = -1


@dataclass(frozen=True)
class IntegratorPlan:
    """What the scene renders with, and what sensaov differentiates with."""

    scene_kind: str  # the scene's integrator, unwrapped ("volpath" inside "moment")
    replay: str  # "prb" or "prbvolpath"
    max_depth: int  # what the replay renders; -1 unbounded
    scene_max_depth: int  # what the scene renders; -1 unbounded
    same_transport: bool  # the replay renders the scene's light transport
    scene_image: dict[str, object] | None  # where the job changes the depth: the replay at the
    # scene's own depth, as a Mitsuba dict


def plan_integrator(
    root: ET.Element, job_max_depth: int | None, changes: list[Change]
) -> IntegratorPlan:
    """Put the replay integrator in place of the scene's; what was done and why is appended to
    ``changes``."""
    written = root.find("integrator")
    user = _unwrapped(written, changes)
    kind = user.get("type", "path") if user is not None else "path"
    has_media = next(root.iter("medium"), None) is not None
    scene_depth = _scene_depth(user, kind)
    depth = scene_depth if job_max_depth is None else job_max_depth
    replay = "prbvolpath" if kind in _VOLUMETRIC or (kind in _LEGACY and has_media) else "prb"
    same = kind in _SAME or kind in _LEGACY or kind == "direct"
    own = _scene_image(replay, scene_depth, user) if same and depth != scene_depth else None
    for element in root.findall("integrator"):
        root.remove(element)
    root.insert(0, _replay_element(replay, depth, user))
    if replay == "prbvolpath":
        _refuse_camera_in_medium(root)
    plan = IntegratorPlan(kind, replay, depth, scene_depth, same, own)
    changes.append(_replacement(plan, job_max_depth, written))
    return plan


def _unwrapped(written: ET.Element | None, changes: list[Change]) -> ET.Element | None:
    user = written
    while user is not None and user.get("type") in _WRAPPERS:
        nested = user.find("integrator")
        if nested is None:
            break  # an aov alone renders no light transport: reported as other transport
        changes.append(
            Change(
                f"integrator {user.get('type')!r} unwrapped: its image is that of the nested "
                f"{nested.get('type', 'path')!r}",
                f"'{user.get('type')}' adds channels (moments, AOVs, Stokes vectors) beside its "
                "nested integrator's image, which is the image M is measured on",
                where(user),
            )
        )
        user = nested
    return user


def _scene_depth(user: ET.Element | None, kind: str) -> int:
    """The depth the scene renders: its max_depth, or the plugin's default."""
    if kind == "direct":
        return 2  # emitters seen, plus one bounce of direct light: prb at depth 2
    if user is None or (text := child_value(user, "max_depth")) is None:
        return _SAME.get(kind, UNBOUNDED)
    try:
        return int(text)
    except ValueError:
        raise SceneError(
            f"integrator max_depth {text!r} is not an integer", where=where(user)
        ) from None


def _replay_element(replay: str, depth: int, user: ET.Element | None) -> ET.Element:
    integrator = ET.Element("integrator", {"type": replay})
    ET.SubElement(integrator, "integer", {"name": "max_depth", "value": str(depth)})
    for setting in list(user) if user is not None else ():
        if setting.get("name") in KEPT_SETTINGS:
            ET.SubElement(integrator, setting.tag, {"name": setting.get("name", ""),
                                                    "value": setting.get("value", "")})  # fmt: skip
    return integrator


def _scene_image(replay: str, scene_depth: int, user: ET.Element | None) -> dict[str, object]:
    """The replay at the scene's own depth, as a Mitsuba dict: the scene's image in expectation,
    so a depth the job changes can be measured against it at the same seed."""
    plugin: dict[str, object] = {"type": replay, "max_depth": scene_depth}
    for name in KEPT_SETTINGS:
        text = child_value(user, name) if user is not None else None
        if text is not None and name == "hide_emitters":
            plugin[name] = text.strip().lower() == "true"
        elif text is not None and text.strip().isdigit():
            plugin[name] = int(text)
    return plugin


def _refuse_camera_in_medium(root: ET.Element) -> None:
    """prbvolpath cannot start paths inside a medium (Mitsuba 3.9.1: "TODO: support sensors
    inside media"): a camera in fog would render without its fog."""
    ids = {m.get("id"): m for m in root.iter("medium") if m.get("id")}
    for sensor in root.iter("sensor"):
        for child in sensor:
            medium = ids.get(child.get("id")) if child.tag == "ref" else child
            if medium is not None and medium.tag == "medium":
                name = medium.get("id") or medium.get("type", "medium")
                raise SceneError(
                    f"camera inside medium {name!r}: prbvolpath, which differentiates media, "
                    "cannot start paths inside a medium (Mitsuba 3.9.1)",
                    where=where(child),
                    hint="move the camera out of the medium, or enclose the medium in a shape",
                )


def _replacement(plan: IntegratorPlan, job_depth: int | None, written: ET.Element | None) -> Change:
    kind, depth, scene_depth = plan.scene_kind, plan.max_depth, plan.scene_max_depth
    shown = "unbounded" if depth == UNBOUNDED else str(depth)
    source = "the scene's" if job_depth is None else "the job's render.max_depth"
    why = "path replay differentiates in constant memory"
    if kind in _LEGACY:
        why += f"; Mitsuba 3 has no '{kind}': the path tracer renders the same light transport"
    if depth != scene_depth:
        old = "unbounded" if scene_depth == UNBOUNDED else str(scene_depth)
        why += f"; the scene renders paths of depth {old}: M is measured on another image"
    if not plan.same_transport:
        why += f"; '{kind}' renders other light transport, so M is measured on another image"
    what = f"integrator {kind!r} -> {plan.replay!r} (max_depth {shown}, {source})"
    altered = not plan.same_transport or depth != scene_depth
    return Change(what, why, where(written) if written is not None else "", altered)
