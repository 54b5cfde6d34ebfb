"""The job's shared display scales for ``sensaov view``: the numbers ``sensaov project`` uses.

A channel's shared scale is read over every camera ``project`` paints (the objective camera and
the job's inspection cameras), traced as ``project`` traces them (same spp, same seed), so the
page's "shared" colours are those of the previews and the EXR display layers
(:func:`~sensaov_cli.views.display_scale.shared_channel_scale`). The passes are traced once, on
opening (or the first request that needs them); each (objective, channel, sign) is computed once.
"""

from __future__ import annotations

import threading
from dataclasses import replace
from typing import cast

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.job.spec import JobSpec
from sensaov_cli.pipeline.project import trace_camera
from sensaov_cli.render.loading import LoadedScene
from sensaov_cli.views.channels import ChannelValues
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.display_scale import DisplayScale, shared_channel_scale
from sensaov_cli.vocabulary import Sign


class JobScales:
    """The job's shared display scale of each painted channel, under either sign."""

    def __init__(
        self, job: JobSpec, buffer: SensitivityBuffer, loaded: LoadedScene, lock: threading.Lock
    ):
        self.job, self.buffer, self.loaded, self._lock = job, buffer, loaded, lock
        self._passes: dict[str, VisibilityPass] = {}
        self._scales: dict[tuple[str, str, str], DisplayScale] = {}

    def of(self, values: ChannelValues, sign: str) -> DisplayScale:
        """The shared scale of ``values``' (objective, channel), its pixels painted ``sign``
        (signed or magnitude), linear: the job's own encoding when it is the default one."""
        key = (values.objective, values.spec.name, sign)
        with self._lock:  # the renderer is not re-entrant
            if key not in self._scales:
                linear = replace(
                    values.spec, sign=cast(Sign, sign), tonemap="none", normalize="none"
                )
                self._scales[key] = shared_channel_scale(
                    self.buffer, linear, values.objective, self._visibilities(),
                    untrusted=self.job.views.untrusted, percentile=self.job.views.percentile,
                )  # fmt: skip
            return self._scales[key]

    def warm(self) -> None:
        """Trace the cameras now (``open_session``), not on the page's first request."""
        with self._lock:
            self._visibilities()

    def _visibilities(self) -> dict[str, VisibilityPass]:
        if not self._passes:
            self._passes = {
                camera.name: trace_camera(self.job, self.buffer, self.loaded, camera, False)
                for camera in self.job.projected_cameras()
            }
        return self._passes
