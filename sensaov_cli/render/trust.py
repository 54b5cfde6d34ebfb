"""Which kinds of parameter have reverse-mode gradients we trust, and why the others are marked.

A (plugin, type) kind is *verified* when its gradient has been shown to agree with central
finite differences (sensaov_cli/fdcheck.py) with Mitsuba 3.9.1:

- ``CHECKED_IN_TESTS``: re-checked by every test run (tests/test_gradients.py);
- ``CHECKED_AT_HIGH_SPP``: their sampling depends on the parameter, so finite differences are
  noisy and agreement only shows at high sample counts (1024 spp, 12 seeds; too slow for the
  test suite). Measured once, recorded in docs/verification.md; the test suite still checks
  that they never *disagree*.

Everything else is reported as unverified, with the reason, so a ranking never presents an
unchecked number as a trusted one. ``sensaov check`` measures any job's own parameters.
"""

from __future__ import annotations

CHECKED_IN_TESTS = frozenset(
    {
        ("diffuse", "reflectance"),  # uniform and bitmap textures
        ("area", "radiance"),
        ("roughplastic", "reflectance"),
        ("roughconductor", "eta"),
        ("roughconductor", "k"),
    }
)
CHECKED_AT_HIGH_SPP = frozenset(
    {("roughdielectric", "roughness"), ("roughdielectric", "eta"), ("roughconductor", "roughness")}
)
VERIFIED = CHECKED_IN_TESTS | CHECKED_AT_HIGH_SPP

KNOWN_BIASED = {
    ("roughplastic", "roughness"): (
        "known biased: Mitsuba's roughplastic alpha gradient comes out 3-6x too small "
        "against finite differences"
    ),
    ("roughplastic", "eta"): (
        "known biased: Mitsuba's roughplastic eta gradient has the wrong sign "
        "against finite differences"
    ),
}


def verification_status(plugin: str, ptype: str) -> tuple[bool, str]:
    """(verified, note) for a parameter of type ``ptype`` held by ``plugin``."""
    if (plugin, ptype) in VERIFIED:
        return True, ""
    known = KNOWN_BIASED.get((plugin, ptype))
    if known:
        return False, known
    return False, f"{plugin} {ptype} gradient not verified against finite differences"
