"""Why a goal can be missed and what would fix it: the notes of ``bench/results.md``.

A figure's note is shown once when any of its cases misses its goal; each missed case adds its
own numbers. Numbers come from the run unless a text says it comes from a one-off profile taken
when the bench was written (named as such, with what was profiled).
"""

from __future__ import annotations

OVERHEAD = (
    "sensaov's extra time is mostly a fixed cost per process, so it weighs most on small jobs. "
    "One-off measurements when issue 23 was last worked on (commit ae9f8bd, 2 cores): on a "
    "16² job at 1 spp, where the passes cost next to nothing, `sensaov run` took 0.18–0.20 s "
    "longer than the script (0.25 s when each process compiled sensaov's bytecode again; the "
    "bench now writes it first). A profile of that run put it at: pydantic's import ≈ 0.06 s "
    "and building the job-spec validator ≈ 0.04 s; PyYAML and click ≈ 0.03 s; sensaov's own "
    "~90 modules ≈ 0.08 s; preparing the scene and writing the outputs ≈ 0.03 s. At 256², "
    "32 spp, Dr.Jit's kernel history shows sensaov's kernels taking as long as the script's "
    "(2.5–2.8 s against 2.5–2.9 s: four sub-passes of 2^19 samples against one pass), but each "
    "sub-pass traces prb's loop again in Python, about 0.1 s more in all. Run-to-run spread of "
    "a 3 s process on this machine is itself ±0.2 s. Fix: keep pydantic off the `run` path "
    "(validate with plain-Python checks and import pydantic only to word an error), the largest "
    "item; then fewer, larger sub-passes (a longer wait for a stop, and results that change "
    "with the sample split), or state the goal for jobs whose passes take ≥ 5 s."
)


def overhead_case(delta: float, script: float) -> str:
    return f"Δ {delta:+.2f} s on {script:.2f} s for the script"


DETERMINISTIC = (
    "'deterministic: true' rows: that setting runs the backward pass on one thread so that "
    "buffers are byte-identical (docs/job-spec.md); each row's detail gives what that costs "
    "against `deterministic: false` (the default) in the same rounds. It has no goal of its "
    "own: it is the price of reproducibility, not pipeline overhead."
)


def adjoint(reference: float) -> str:
    return (
        "The 'Mitsuba alone' rows call `prb.render_backward` directly and read the gradients "
        "back, with no sensaov code. Most of the multiple is inside prb: its backward runs a "
        "primal-mode pass to re-estimate the radiance, then an adjoint pass over the same paths "
        "that also differentiates the BSDFs and emitters and scatter-adds every parameter's "
        "gradient with atomics; on these scenes (rough plastic, rough dielectric, a texture) "
        "that adjoint pass costs more than a primal pass. On Mitsuba's diffuse-only "
        f"`cornell_box()` the same measurement gives {reference:.2f}× (reference row; "
        "MITSUBA-NOTES measured ≈ 1.9× on a Cornell box). sensaov's backward keeps its "
        "gradient-enabled leaves from one pass to the next over the same keys (issue 23: "
        "`params.update()` re-derives every BSDF's tables, 0.1–0.25 s a call on the interior), "
        "so what it adds to Mitsuba's pass is reading the gradients back, and its sub-passes: "
        "spp is split into sub-passes of at most 2^19 samples (`SAMPLES_PER_SUBPASS` in "
        "render/adjoint.py: a stop is acted on between them, and small parameters' gradients "
        "are summed over them in float64), so from 256² at 32 spp sensaov calls "
        "`render_backward` 4 times where the script calls it once, and each call traces prb's "
        "loop again in Python. A one-off what-if (commit e251fa0, 256², 32 spp, 5 interleaved "
        "rounds, sensaov's backward / Mitsuba's at sub-passes of 2^19 / 2^20 / 2^21 samples): "
        "interior 1.06× / 1.03× / 0.99×, cbox 1.07× / 1.05× / 1.06×; Dr.Jit's kernel history "
        "put the interior's time outside kernels at 0.14 s in 4 sub-passes against 0.03 s in "
        "Mitsuba's one. Fix: re-base the goal at ≈ 2.4× for glossy and refractive "
        "scenes under prb on the LLVM backend (and measure it on a GPU); larger sub-passes "
        "trade a longer wait for a stop and float32 sums (docs/verification.md: the duality "
        "residuals stay under 1e-4 only up to 2^19) for the tracing."
    )


def adjoint_case(ratio: float, alone: float) -> str:
    return f"sensaov {ratio:.2f}×, Mitsuba alone {alone:.2f}×"


TEXTURE = (
    "The texture's cost is per backward pass: its gradient components are scatter-added with "
    "atomics, cleared and copied to numpy. It does not grow with resolution or spp, so it "
    "weighs less on bigger renders. Fix: pool texel gradients on the device before copying "
    "them, or keep very large textures out of the selection (`parameters.exclude`) when only "
    "their total matters."
)


def texture_case(delta: float) -> str:
    return f"{delta:+.3f} s per pass"


OBJECTIVES = (
    "Each extra objective is one backward pass plus dM/dI (a small kernel over the image); a "
    "median a few per cent above 1 with min/max around 1 is timing noise on a shared machine "
    "(the costs are differences: T(K) − T(1)). A clear excess would point at per-objective "
    "work outside the pass (e.g. recompiling the objective's kernel for each objective)."
)

PROJECTION = (
    "The 'visibility trace alone' rows show what tracing the rays costs; the rest of a view "
    "does not shrink with the adjoint. A profile of two views without beauty (pyinstrument, "
    "cbox 512², 16 visibility spp, two objectives × three channel kinds: 18 sensitivity "
    "layers, each with its RGB display layer, and two Cryptomattes: 96 channels), issue 23, "
    "on 2 cores: about 0.56 s a view under the profiler, of which `visibility.trace` ≈ "
    "0.17 s (the kernel and its read-back 0.135 s, per-pixel histogram and ranks 0.035 s), "
    "the layered EXR ≈ 0.20 s (ZIP of 96 channels on both cores ≈ 0.17 s: this alone is "
    "about one trace), the display scales ≈ 0.035 s, painting ≈ 0.03 s, the display layers "
    "≈ 0.03 s, CryptoMaterial ≈ 0.025 s. Before issue 23 the same view was 1.75 s (display "
    "colours per pixel, a single-threaded EXR write, sorts of data already in order); at the "
    "start of its last session 1.06 s, then float64 copies, full sorts and re-checks of "
    "orders that the data already had went (commits f2e941a..ae50ff9, every output bit for "
    "bit the same). The beauty pass is a path-traced render (4 spp by default), which costs "
    "a quarter of a primal at 16 spp; the objective camera reuses primal.exr instead. A "
    "view's cost does not depend on the job's spp while the adjoint's grows linearly with "
    "it, hence the second comparison against the example jobs' spp. Why ≤ 1.5× the trace "
    "stays out of reach here: the EXR write alone costs about one trace, but dropping it is "
    "not enough. A one-off what-if (commit e251fa0, the view without beauty against the trace "
    "alone, 5 interleaved rounds, cbox / interior): as written 3.66× / 2.62×; ZSTD instead of "
    "ZIP (OpenEXR 3.4+ reads it) 2.92× / 2.41×; no display layers 2.90× / 2.14×; both "
    "2.39× / 1.92×. What is left then is numpy work over 18 layers of 512² pixels on 2 cores "
    "(painting ≈ 0.035 s, display scales ≈ 0.03 s, the two Cryptomattes' ranks ≈ 0.035 s, "
    "the per-pixel histogram ≈ 0.025 s) against a trace of 0.13–0.17 s. Fix: re-base the goal "
    "(the trace is the only part a GPU speeds up, so there the ratio grows), or state it "
    "against the adjoint at the example jobs' spp, which the view meets."
)


def projection_case(view: float, trace: float) -> str:
    return f"view {view:.2f} s, of which `trace` {trace:.2f} s"


def memory_spp(hi: float, lo: float) -> str:
    return (
        f"{hi:.0f} MB vs {lo:.0f} MB: prb is meant to be constant-memory in spp; growth means "
        "something proportional to spp × pixels is kept alive (Dr.Jit launches all samples of "
        "a pass as one wavefront). Fix: render in passes of fewer samples (the integrator's "
        "`samples_per_pass`)"
    )


def memory_primal(extra_mb: float, backward_mb: float) -> str:
    return (
        f"`sensaov run` holds {extra_mb:.0f} MB more than the primal alone, while the script's "
        f"own backward pass adds {backward_mb:.0f} MB (reference row): the rest is what sensaov "
        "imports and the script does not (pydantic, OpenEXR, click) and the copies it keeps "
        "for the buffer. Fix: keep pydantic off the run path; release Dr.Jit arrays before "
        "writing the outputs"
    )


STARTUP = (
    "Start-up is imports plus, for `rank`, reading and validating every array of the buffer "
    "(`np.isfinite` over all components). `python -X importtime -m sensaov_cli …` lists the "
    "slowest imports; an import of mitsuba or drjit on these paths is a bug (they take "
    "≈ 0.2 s by themselves)."
)


LIVE_VIEW = (
    "A live view is one primary-visibility pass plus numpy work on its pixels: the histogram "
    "of each pixel's samples, painting, the colour map and the PNG. Past the goal, profile "
    "`ViewSession.view` (cProfile) before changing the kernel: the trace itself is a few "
    "milliseconds at 256², 1 spp, and a kernel compiled anew on a move would show in the "
    "'kernels compiled' row."
)


INTERIOR = (
    "`sensaov rank` reads each parameter's stored sums (format 4) and never a texel, so what "
    "is left is start-up and the header: on this shared machine (load 2-3, tree db28a07) "
    "importing the command line and rank's modules (Python, click, numpy) took 0.24-0.31 s, "
    "about all of the kitchen's 0.25 s, and 8,000 parameters add about 0.2 s of JSON, "
    "records and grouping in Python. A miss means a loaded machine "
    "(compare the in-process 'lazy' read row) or a buffer without sums (another writer), which "
    "is ranked from its arrays."
)

BATCHES = (
    "The default splits render.spp into 8 batches: the same samples, but every pass (a primal, "
    "a backward pass per objective, a forward pass per batch) is traced again by Mitsuba for "
    "each batch, a fixed cost per call that compiled kernels do not remove; and repairs take "
    "one seed per batch (8 instead of repair.seeds' 4), each render with its own fixed cost. "
    "One-off stage timings when this figure was written (2 shared cores, llvm): "
    "configs/cbox.yaml backward passes 11.1 s against 8.0 s, primals 1.8 s against 1.4 s, "
    "forward passes unchanged (22.2 s against 21.7 s); configs/interior.yaml backward 6.2 s "
    "against 5.6 s, repairs 11.9 s against 6.5 s (192 renders against 96). Fix: frozen "
    "functions (dr.freeze) for the passes, so that a batch costs its kernels only; or "
    "`batches: 1` where error bars are not wanted."
)
