"""Preparing a user's scene for differentiation (pure XML: no Mitsuba import).

The face is :func:`prepare_scene`: a job's scene reference in, a :class:`PreparedScene` out.
Every command prepares its scene once and passes that value down.
"""

from sensaov_cli.scene.prepare import PreparedScene, prepare_scene

__all__ = ["PreparedScene", "prepare_scene"]
