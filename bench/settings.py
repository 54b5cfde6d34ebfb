"""How big and how often: the full run of ``make bench`` and the tiny ``--quick`` one."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Settings:
    quick: bool
    variant: str  # as written in the generated jobs ("auto", "llvm_ad_rgb", "cuda_ad_rgb")
    rounds: int  # timed rounds of an in-process comparison (after one warm-up round)
    process_rounds: int  # timed rounds of a whole-process comparison
    view_rounds: int  # timed rounds of figure 4 (its 64-spp adjoint at 512² dominates the bench)
    startup_rounds: int  # timed rounds of the start-up figure (cheap processes)
    resolutions: tuple[int, int]  # square objective images, the "two resolutions"
    spp: int  # samples per pixel of the objective renders
    texture: int  # side of the texture of figures 3 and 7
    view: int  # side of the inspection view of figure 4
    view_spp: int  # spp of the adjoint pass figure 4 compares with
    job_spp: int  # spp of the example jobs (configs/*.yaml), figure 4's second comparison
    vis_spp: int  # visibility samples of figure 4's view
    memory_resolution: int
    memory_spp: tuple[int, int]
    io_texture: int  # side of the RGB gradient of figure 9
    live_view: int = 256  # side of figure 13's live views (the issue's 256²)
    live_views: int = 60  # timed views of figure 13, each from a new camera

    def describe(self) -> str:
        kind = "quick (development only: numbers mean nothing)" if self.quick else "full"
        lo, hi = self.resolutions
        return (
            f"Settings ({kind}): variant `{self.variant}`, objective images {lo}² and {hi}² at "
            f"{self.spp} spp, max_depth 6; {self.rounds} timed rounds in-process "
            f"({self.view_rounds} for figure 4), {self.process_rounds} for whole-process "
            f"comparisons, {self.startup_rounds} for "
            "start-up, each after one untimed warm-up round; sides interleaved within a round."
        )


def full(variant: str) -> Settings:
    return Settings(
        quick=False,
        variant=variant,
        rounds=5,
        process_rounds=4,
        view_rounds=3,
        startup_rounds=10,
        resolutions=(128, 256),
        spp=32,
        texture=1024,
        view=512,
        view_spp=16,
        job_spp=64,
        vis_spp=16,
        memory_resolution=128,
        memory_spp=(64, 256),
        io_texture=2048,
    )


def quick(variant: str) -> Settings:
    return Settings(
        quick=True,
        variant=variant,
        rounds=2,
        process_rounds=2,
        view_rounds=2,
        startup_rounds=2,
        resolutions=(32, 48),
        spp=4,
        texture=128,
        view=64,
        view_spp=4,
        job_spp=8,
        vis_spp=4,
        memory_resolution=32,
        memory_spp=(4, 16),
        io_texture=256,
        live_view=64,
        live_views=8,
    )
