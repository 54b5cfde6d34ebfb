"""Preparing a user's scene for differentiation (pure XML: no Mitsuba import).

The face is :func:`prepare_scene`: a job's scene reference in, a :class:`PreparedScene` out
(the text Mitsuba loads, where it resolves names, the fingerprint, every file read, the names
given to unnamed objects, and what was rewritten and why). Every command prepares its scene
once and passes that value down. Inside: ``source`` (XML with file and line, the changes and
refusals told there), ``expand`` (includes, arguments, paths and old formats, as Mitsuba's
parser reads them), ``legacy`` (what 3.9.1 lacks of 0.5/0.6), ``declared_sizes`` (images and
meshes measured before loading), ``naming``, ``sharing``, ``sensors`` and ``integrator`` (what
sensaov changes), ``prepare`` (all of it, in order).
"""

from sensaov_cli.scene.prepare import PreparedScene, SceneChange, prepare_scene

__all__ = ["PreparedScene", "SceneChange", "prepare_scene"]
