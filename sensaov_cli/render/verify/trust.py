"""How far each kind of reverse-mode gradient can be trusted, as measured (docs/verification.md).

A kind is a (plugin, type) pair: a parameter's holder and slot. Labels come from
``scripts/trust_table.py`` (gradients of a tiny scene per plugin against central differences);
docs/verification.md holds its output, and tests/test_trust.py keeps the two in step. A kind
missing from the table is "unverified".

prb differentiates a BSDF through ``bsdf.eval``, which is 0 for a delta lobe: parameters of
smooth BSDFs take their gradients from Mitsuba's ``path`` instead.
"""

from __future__ import annotations

from dataclasses import dataclass

from sensaov_cli.vocabulary import Trust

MITSUBA = "Mitsuba 3.9.1"
DELTA_PLUGINS = frozenset({"conductor", "dielectric", "plastic", "thindielectric"})
DELTA_LOBE_REASON = (
    f"smooth (delta) BSDF lobe: {MITSUBA}'s prb differentiates BSDFs through eval(), which is "
    "0 for delta lobes"
)
ZERO_VALUE_REASON = (
    f"value exactly 0: zero throughput ends the path {MITSUBA} replays, so the derivative at 0 "
    "is lost"
)
SPOT_TEXTURE_REASON = (
    f"{MITSUBA}'s spot light uses its texture only when it varies over the beam (a bitmap): "
    "this uniform value has no effect"
)
# Principled parameters that switch a lobe on: Mitsuba evaluates only the lobes a scene sets.
PRINCIPLED_LOBES = frozenset(
    {"anisotropic", "clearcoat", "clearcoat_gloss", "flatness", "metallic", "sheen",
     "sheen_tint", "spec_tint", "spec_trans"}
)  # fmt: skip
PRINCIPLED_LOBE_REASON = (
    f"{MITSUBA}'s principled evaluates only the lobes the scene sets (decided at load): this "
    "parameter's lobe is off, so it has no effect"
)
NO_FLOW_REASON = (
    f"{MITSUBA} propagated no gradient to this parameter (it may not affect M at all: off "
    "frame and on no sampled light path)"
)


@dataclass(frozen=True)
class Entry:
    trust: Trust
    note: str = ""  # what a record of this kind says about its gradient ("" when verified)


VERIFIED = Entry("verified")
_PATH_PLASTIC = (
    f"known biased: {MITSUBA}'s path integrator (prb gives 0 or worse for smooth plastic) "
    "differentiates the lobe-selection weight"
)


def _noisy(kind: str) -> Entry:
    return Entry("unverified", f"{kind} gradient: measured, too noisy to tell at 32x32/1024 spp")


# (plugin, type) -> label: the weakest of the kind's rows in docs/verification.md.
TABLE: dict[tuple[str, str], Entry] = {
    ("area", "radiance"): VERIFIED,
    ("conductor", "eta"): VERIFIED,  # through path, like every parameter of a smooth BSDF
    ("conductor", "k"): VERIFIED,
    ("conductor", "specular"): VERIFIED,
    ("constant", "radiance"): VERIFIED,
    ("dielectric", "specular"): VERIFIED,
    ("dielectric", "transmittance"): VERIFIED,
    ("diffuse", "reflectance"): VERIFIED,  # uniform, bitmap, checkerboard, twosided, blended
    ("directional", "radiance"): VERIFIED,
    ("envmap", "radiance"): VERIFIED,  # data (through our own leaf) and scale
    # media, differentiated by prbvolpath (a medium in a null sphere, rendered by volpath)
    ("heterogeneous", "albedo"): VERIFIED,
    ("heterogeneous", "sigma_t"): VERIFIED,
    ("hg", "g"): VERIFIED,
    ("homogeneous", "albedo"): VERIFIED,
    ("homogeneous", "sigma_t"): VERIFIED,
    ("plastic", "reflectance"): Entry("biased", f"{_PATH_PLASTIC}: 6 % too high, measured"),
    ("plastic", "specular"): Entry("biased", f"{_PATH_PLASTIC}: 60 % too low, measured"),
    ("point", "radiance"): VERIFIED,
    ("principled", "anisotropic"): _noisy("principled anisotropic"),
    ("principled", "clearcoat"): _noisy("principled clearcoat"),
    ("principled", "clearcoat_gloss"): _noisy("principled clearcoat_gloss"),
    ("principled", "flatness"): VERIFIED,
    ("principled", "metallic"): VERIFIED,
    ("principled", "reflectance"): VERIFIED,
    ("principled", "roughness"): _noisy("principled roughness"),
    ("principled", "sheen"): VERIFIED,
    ("principled", "sheen_tint"): VERIFIED,
    ("principled", "spec_tint"): VERIFIED,
    ("principled", "spec_trans"): VERIFIED,
    ("principled", "specular"): VERIFIED,
    ("roughconductor", "eta"): VERIFIED,
    ("roughconductor", "k"): VERIFIED,
    ("roughconductor", "roughness"): VERIFIED,
    ("roughdielectric", "eta"): VERIFIED,
    ("roughdielectric", "roughness"): VERIFIED,
    ("roughplastic", "eta"): Entry(
        "biased",
        "known biased: Mitsuba's roughplastic eta gradient has the wrong sign against finite "
        "differences",
    ),
    ("roughplastic", "reflectance"): VERIFIED,
    ("roughplastic", "roughness"): Entry(
        "biased",
        "known biased: Mitsuba's roughplastic alpha gradient comes out 3-25x too small against "
        "finite differences",
    ),
    ("spot", "beam_width"): VERIFIED,
    ("spot", "cutoff_angle"): VERIFIED,
    ("spot", "radiance"): VERIFIED,  # intensity and a bitmap texture
    ("thindielectric", "eta"): Entry(
        "no_gradient",
        f"{MITSUBA}'s thindielectric picks reflection or transmission with its Fresnel term as "
        "the probability and 1 as the weight: eta acts only through that choice, which neither "
        "prb nor path differentiates",
    ),
    ("thindielectric", "transmittance"): VERIFIED,
}


# --- composites: trust follows the whole path a gradient takes --------------------------------
#
# A parameter inside a composite BSDF (or of one) has a context per composite above it:
# (composite, role, children): role is the composite's own slot for its own parameters, "child"
# for those of the BSDFs inside it; children is "smooth" where a child has a delta lobe, else
# "rough". Its label is the weakest of its kind's and each context's (docs/verification.md).
Context = tuple[str, str, str]
WEAKEST_FIRST: tuple[Trust, ...] = ("no_gradient", "biased", "suspect", "unverified", "verified")
COMPOSITES = frozenset({"blendbsdf", "mask", "twosided", "bumpmap", "normalmap"})
_BLEND_WEIGHT = (
    f"known biased: a blendbsdf with a smooth (delta) child: {MITSUBA}'s prb differentiates the "
    "weight through eval(), 0 for the smooth lobe, and path through the choice of the lobe, "
    "which it does not differentiate; measured with the wrong sign against finite differences"
)
_BUMP_SMOOTH = (
    f"known biased: a bump map over a smooth (delta) BSDF turns the mirror direction; neither "
    f"{MITSUBA}'s prb nor path differentiates that (measured: -4e-4 against +0.16 from finite "
    "differences)"
)
_NORMAL_SMOOTH = (
    "not verified: a normal map over a smooth (delta) BSDF turns the mirror direction, which "
    f"{MITSUBA}'s path differentiates only in part; measured at 35 % of the finite difference, "
    "too noisy to call (12 seeds, AD 256 spp, FD 4096 spp)"
)
COMPOSITE_TABLE: dict[Context, Entry] = {
    ("blendbsdf", "weight", "rough"): VERIFIED,
    ("blendbsdf", "weight", "smooth"): Entry("biased", _BLEND_WEIGHT),
    ("blendbsdf", "child", "rough"): VERIFIED,
    ("blendbsdf", "child", "smooth"): VERIFIED,  # through path: prb is biased there
    ("mask", "opacity", "rough"): VERIFIED,  # through path: the pass-through lobe is delta
    ("mask", "opacity", "smooth"): VERIFIED,
    ("mask", "child", "rough"): VERIFIED,
    ("mask", "child", "smooth"): VERIFIED,
    ("twosided", "child", "rough"): VERIFIED,
    ("twosided", "child", "smooth"): VERIFIED,
    ("bumpmap", "bump", "rough"): VERIFIED,
    ("bumpmap", "bump", "smooth"): Entry("biased", _BUMP_SMOOTH),
    ("bumpmap", "child", "rough"): VERIFIED,
    ("bumpmap", "child", "smooth"): VERIFIED,
    ("normalmap", "normal", "rough"): VERIFIED,
    ("normalmap", "normal", "smooth"): Entry("unverified", _NORMAL_SMOOTH),
    ("normalmap", "child", "rough"): VERIFIED,
    ("normalmap", "child", "smooth"): VERIFIED,
}
# Contexts whose parameters path differentiates, or none does well: prb differentiates a
# composite through eval(), in which a delta lobe (a smooth child, a mask's pass-through) is 0.
_PATH_CONTEXTS = frozenset(
    {("blendbsdf", "weight", "smooth"), ("blendbsdf", "child", "smooth"),
     ("mask", "opacity", "rough"), ("mask", "opacity", "smooth"),
     ("bumpmap", "bump", "smooth"), ("normalmap", "normal", "smooth")}
)  # fmt: skip


def composite_status(contexts: tuple[Context, ...]) -> tuple[Trust, str]:
    """The weakest label of ``contexts`` (composites above a parameter), and their notes."""
    statuses: list[tuple[Trust, str]] = [("verified", "")]
    for composite, role, children in contexts:
        unknown: tuple[Trust, str] = (
            "unverified",
            f"{role} of a {composite} over {children} children: not verified against "
            "finite differences",
        )
        entry = COMPOSITE_TABLE.get((composite, role, children))
        statuses.append((entry.trust, entry.note) if entry else unknown)
    return weakest(*statuses)


def weakest(*statuses: tuple[Trust, str]) -> tuple[Trust, str]:
    """The weakest label of ``statuses`` and the notes of all that are not verified."""
    trust = min((t for t, _ in statuses), key=WEAKEST_FIRST.index)
    notes = [note for t, note in statuses if t != "verified" and note]
    return trust, "; ".join(dict.fromkeys(notes))


# --- repairs: where the reverse-mode gradient is known wrong, finite differences instead ------

COMPOSITE_REASON = (
    f"composite over a smooth (delta) lobe: {MITSUBA}'s prb differentiates it through eval(), "
    "which omits that lobe"
)


@dataclass(frozen=True)
class RepairEntry:
    """How a kind's finite-difference repair (render/verify/repair.py) was measured to do."""

    trust: Trust  # the label a repaired gradient of this kind gets
    step: float  # relative step ε / max(1, |θ|) it was measured with, and uses
    note: str = ""


REPAIR_STEP = 0.01  # the step of a kind not listed below
# (plugin, type) -> the repair's label and step, measured against independent central
# differences (docs/verification.md "Repairs", scripts/repair_table.py).
REPAIRS: dict[tuple[str, str], RepairEntry] = {
    ("blendbsdf", "weight"): RepairEntry("verified", 0.1),  # lobe flips: noise grows as 1/ε
    ("diffuse", "reflectance"): RepairEntry(  # components at 0: one-sided differences
        "unverified",
        0.05,
        "diffuse reflectance: its repair at a component 0 was measured "
        "3.1 standard errors from central differences (docs/verification.md)",
    ),
    ("plastic", "reflectance"): RepairEntry("verified", 0.05),
    ("roughplastic", "eta"): RepairEntry("verified", 0.01),
    ("roughplastic", "roughness"): RepairEntry("verified", 0.01),
}


def repair_entry(plugin: str, ptype: str) -> RepairEntry:
    """The measured repair of a kind, or an unverified one at the default step."""
    found = REPAIRS.get((plugin, ptype))
    if found is not None:
        return found
    note = f"{plugin} {ptype}: its finite-difference repair is not measured for this kind"
    return RepairEntry("unverified", REPAIR_STEP, note)


# --- checks: which kinds one seed checks -----------------------------------------------------

# (plugin, type, is_texture) of kinds whose value does not steer sampling: a difference at the
# reverse pass's own seed reproduces its gradient to float precision, so `sensaov check`
# compares them at one seed; the others over seeds.
SAME_SEED_EXACT = frozenset(
    {("diffuse", "reflectance", False), ("diffuse", "reflectance", True),
     ("conductor", "eta", False), ("conductor", "k", False), ("conductor", "specular", False),
     ("roughconductor", "eta", False), ("roughconductor", "k", False),
     ("dielectric", "specular", False), ("dielectric", "transmittance", False),
     ("thindielectric", "transmittance", False), ("principled", "reflectance", False),
     ("area", "radiance", False), ("point", "radiance", False),
     ("directional", "radiance", False), ("constant", "radiance", False),
     ("spot", "radiance", False), ("spot", "radiance", True), ("envmap", "radiance", False)}
)  # fmt: skip


def known_zero_reason(
    plugin: str, ptype: str, key: str, integrator: str, all_zero: bool
) -> str | None:
    """Why a parameter differentiated by ``integrator`` can get an identically zero gradient."""
    if plugin in DELTA_PLUGINS and integrator == "prb":
        return DELTA_LOBE_REASON
    if all_zero:
        return ZERO_VALUE_REASON
    if plugin == "spot" and key.endswith(".texture.value"):
        return SPOT_TEXTURE_REASON
    if plugin == "principled" and ptype in PRINCIPLED_LOBES:
        return PRINCIPLED_LOBE_REASON
    return None


def gradient_integrator(plugin: str, contexts: tuple[Context, ...] = ()) -> str:
    """The integrator whose backward pass differentiates a parameter held by ``plugin``, inside
    the composites ``contexts``."""
    if plugin in DELTA_PLUGINS or any(c in _PATH_CONTEXTS for c in contexts):
        return "path"
    return "prb"


def verification_status(plugin: str, ptype: str) -> tuple[Trust, str]:
    """(label, note) the table gives a parameter of type ``ptype`` held by ``plugin``."""
    entry = TABLE.get((plugin, ptype))
    if entry is None:
        return "unverified", f"{plugin} {ptype} gradient not verified against finite differences"
    return entry.trust, entry.note
