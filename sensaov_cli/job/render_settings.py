"""How ``run`` renders: the objective camera's passes (``render:``) and the repairs of the
gradients Mitsuba gets wrong (``repair:``); part of the job (job.py), standard library only."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from annotated_types import Ge, Gt, Le, Lt

from sensaov_cli.job.fields import STRICT, MaxDepth, Resolution
from sensaov_cli.job.markers import Doc, Section
from sensaov_cli.job.problems import Problem


@dataclass(frozen=True)
class RenderSpec(Section):
    """How the objective camera's image is rendered and differentiated."""

    spp: Annotated[int, STRICT, Ge(1), Lt(2**32), Doc("Samples per pixel (32-bit).")] = 64
    max_depth: Annotated[
        MaxDepth | None,
        Doc(
            "Longest path; -1 = unbounded; null = the scene's own (its integrator's max_depth, "
            "or that integrator's default)."
        ),
    ] = None
    seed: Annotated[int, STRICT, Ge(0), Lt(2**31), Doc("Sampler seed.")] = 0
    resolution: Annotated[
        Resolution | None,
        Doc("[width, height] of the objective render; null = its film's size."),
    ] = None
    deterministic: Annotated[
        bool,
        STRICT,
        Doc(
            "Byte-identical buffers for the same job and seed: on the CPU backend the "
            "backward passes then run on one thread (parallel atomic adds sum in varying "
            "order). Off by default: the differences are far below Monte Carlo noise."
        ),
    ] = False
    batches: Annotated[
        int,
        STRICT,
        Ge(1),
        Le(1024),
        Doc(
            "Independent batches of spp/batches samples, each with its own primal and backward "
            "passes; with 2 or more the buffer stores standard errors (docs/farm.md)."
        ),
    ] = 1

    def __post_init__(self) -> None:
        if self.batches > self.spp:
            raise Problem(
                f"batches ({self.batches}) cannot exceed spp ({self.spp})", at=("batches",)
            )


@dataclass(frozen=True)
class RepairSpec(Section):
    """Gradients Mitsuba is known to get wrong, computed again by finite differences."""

    budget: Annotated[
        float,
        STRICT,
        Ge(0),
        Le(1000),
        Doc(
            "Extra samples for repairs, a multiple of the run's own (its primal and backward "
            "passes); 0 repairs nothing. What does not fit stays labelled and is named."
        ),
    ] = 1.0
    seeds: Annotated[
        int,
        STRICT,
        Ge(2),
        Le(64),
        Doc(
            "Seeds per repair: both sides of a difference share a seed's samples, the "
            "standard error comes from the seeds' spread."
        ),
    ] = 4
    step: Annotated[
        float | None,
        STRICT,
        Gt(0),
        Le(0.5),
        Doc("Relative step: ε = step · max(1, |θ|); null = the measured step of each kind."),
    ] = None
