"""Wire ``sensaov params``: spec -> prepared scene -> loaded scene -> the parameter inventory."""

from __future__ import annotations

from sensaov_cli.job.spec import JobSpec
from sensaov_cli.outputs.tables import ParameterInventory
from sensaov_cli.render.loading import load_scene
from sensaov_cli.render.verify.repair import planned
from sensaov_cli.scene import prepare_scene


def parameter_inventory(job: JobSpec) -> ParameterInventory:
    """Which parameters of the job's scene enter the buffer, and what was changed to load it."""
    prepared = prepare_scene(job)
    loaded = load_scene(prepared, variant=job.variant, parameters=job.parameters)
    return ParameterInventory(
        variant=loaded.variant,
        objects=loaded.objects,
        selected=loaded.selected,
        excluded=loaded.excluded,
        split=prepared.split,
        textures=loaded.textures,
        changes=tuple((c.what, c.why, c.where, c.alters_image) for c in prepared.changes),
        repairs=planned(loaded) if job.repair.budget > 0 else {},
    )
