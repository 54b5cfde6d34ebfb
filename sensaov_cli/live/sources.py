"""What ``sensaov view`` can paint, per objective: the job's channels, a typed select query, and
the forward and transport layers stored beside the buffer.

Object, type and select channels are per-object values computed once from the buffer and painted
through any camera. A select query typed in the page (``select:<glob>``) becomes a channel the
same way, on first use. Forward and transport layers are different in kind: images of the
objective camera rendered by ``sensaov run`` (§4, §7), which no other viewpoint can re-project;
they are offered at that camera only, and say so.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from sensaov_cli.buffer.forward_sidecar import check_belongs, read_forward
from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.queries import select
from sensaov_cli.buffer.statistics import single_pass
from sensaov_cli.errors import RequestError, UnknownNameError
from sensaov_cli.job.spec import ChannelSpec, JobSpec
from sensaov_cli.pipeline.run import FORWARD_NAME
from sensaov_cli.views.channels import ChannelValues, channel_values
from sensaov_cli.views.texels import PANELS, TexelField, texture_token
from sensaov_cli.views.transport import forward_views, transport_views

SELECT_PREFIX = "select:"
OBJECTS = ChannelSpec("objects", "object")  # offered even when a job lists no object channel


@dataclass(frozen=True, eq=False)
class StoredImage:
    """A layer of the objective camera: ``data`` (H, W), linear, with what it is."""

    name: str
    kind: str  # "forward" | "transport"
    data: np.ndarray
    keys: tuple[str, ...]
    unverified: tuple[str, ...]
    note: str  # the duality check of a transport layer; the colour reduction of a forward one


@dataclass(frozen=True, eq=False)
class TexelPanel:
    """One of Fig. 4's panels of a texel field: painted through the hit UVs of each view."""

    field: TexelField
    panel: str  # "object" | "texel" | "joint"


class Sources:
    """Every channel of every objective, by name; typed select queries added on first use."""

    def __init__(
        self,
        job: JobSpec,
        buffer: SensitivityBuffer,
        buffer_path: Path,
        fields: list[TexelField],
    ):
        self.buffer = buffer
        has_objects = any(c.kind == "object" for c in job.channels)
        specs = job.channels if has_objects else (OBJECTS, *job.channels)
        self.untrusted = job.views.untrusted
        self.painted = {
            (v.objective, v.pass_name): v
            for v in channel_values(buffer, specs, untrusted=self.untrusted)
        }
        self.images = _stored_images(job, buffer, buffer_path)
        self.texels = {
            (f.objective, f"{f.channel.name}_{texture_token(f.record.key)}_{panel}"): (
                TexelPanel(f, panel)
            )
            for f in fields
            for panel in PANELS
        }  # the names project gives these layers

    def names(self) -> list[str]:
        """Channel names in the order the job lists them, then the stored layers."""
        painted = dict.fromkeys(name for _, name in self.painted)
        texels = dict.fromkeys(name for _, name in self.texels)
        return [*painted, *texels, *dict.fromkeys(name for _, name in self.images)]

    def objective_only(self) -> list[str]:
        return list(dict.fromkeys(name for _, name in self.images))

    def find(self, objective: str, channel: str) -> ChannelValues | StoredImage | TexelPanel:
        self.buffer.objective(objective)  # UnknownNameError (HTTP 400) names the known ones
        if (objective, channel) in self.painted:
            return self.painted[(objective, channel)]
        if (objective, channel) in self.texels:
            return self.texels[(objective, channel)]
        if (objective, channel) in self.images:
            return self.images[(objective, channel)]
        if channel.startswith(SELECT_PREFIX):
            return self._query(objective, channel)
        raise UnknownNameError("channel", channel, [*self.names(), f"{SELECT_PREFIX}<glob>"])

    def _query(self, objective: str, channel: str) -> ChannelValues:
        glob = channel[len(SELECT_PREFIX) :]
        if not glob or not select(self.buffer, glob=glob):
            raise RequestError(
                f"select query {glob!r} matches no parameter of the buffer",
                hint="globs match keys such as 'white.reflectance.value' or '*.alpha'",
            )
        spec = ChannelSpec(f"select_{len(self.painted)}", "select", select=glob)
        for values in channel_values(self.buffer, (spec,), untrusted=self.untrusted):
            part = values.pass_name[len(spec.name) :]  # "" or the untrusted part's suffix
            self.painted[(values.objective, channel + part)] = replace(
                values, pass_name=channel + part
            )
        return self.painted[(objective, channel)]


def _stored_images(
    job: JobSpec, buffer: SensitivityBuffer, buffer_path: Path
) -> dict[tuple[str, str], StoredImage]:
    """The forward and transport layers of the sidecar, under every objective they apply to."""
    path = buffer_path.with_name(FORWARD_NAME)
    if not job.wants_forward or not single_pass(buffer.provenance) or not path.exists():
        return {}
    data = read_forward(path)
    check_belongs(data, buffer, path)
    found: dict[tuple[str, str], StoredImage] = {}
    for f in forward_views(buffer, data):
        if f.data is None:
            continue
        mono = f.data if f.data.ndim == 2 else f.data.mean(axis=2)
        note = "mean of the R, G, B derivatives" if f.data.ndim == 3 else ""
        image = StoredImage(f"forward.{f.name}", "forward", mono, f.keys, f.unverified, note)
        for objective in buffer.objectives:
            found[(objective.name, image.name)] = image
    for t in transport_views(buffer, data):
        verdict = "agrees" if t.agrees else "EXCEEDS TOLERANCE: do not trust this layer"
        note = f"duality residual {t.residual:.2e} (tolerance {t.tolerance:.0e}): {verdict}"
        found[(t.objective, t.name)] = StoredImage(
            t.name, "transport", t.data, t.keys, t.unverified, note
        )
    return found
