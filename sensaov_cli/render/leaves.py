"""The gradient-enabled leaves a pass differentiates: fresh ones, or the previous pass's.

A Mitsuba scene only takes a new leaf through ``params.update()``, which re-derives the state
of every object that holds one (a rough plastic's tables, a bitmap's texture); on
scenes/interior that costs 0.1-0.25 s a call, a tenth of a 128² backward pass (issue 23).
"""

from __future__ import annotations

from typing import Any

from sensaov_cli.render.loading import LoadedScene


def enable_gradients(loaded: LoadedScene, keys: set[str] | None = None) -> dict[str, Any]:
    """Give every selected parameter a fresh leaf of its own; gradients on ``keys`` (default all).

    The gradient is read from our leaf, never from ``params[key]``: an envmap's update replaces
    the tensor that ``params[key]`` refers to by a copy with its halo columns filled in, and the
    gradient of that copy reads 0 (Mitsuba 3.9.1, docs/verification.md). The other parameters
    hold the leaf itself. Leaves not in ``keys`` are detached, so a pass differentiates nothing
    else (prb raises if only delta-lobe parameters carry gradients; path's memory grows with them).
    """
    import drjit as dr

    leaves = {}
    for info in loaded.selected:
        current = loaded.params[info.key]
        leaf = type(current)(dr.detach(current))
        if keys is None or info.key in keys:
            dr.enable_grad(leaf)
        loaded.params[info.key] = leaf
        leaves[info.key] = leaf
    loaded.held_leaves = None  # fresh leaves: none a pass may reuse (see pass_leaves)
    loaded.params.update()  # bitmap and envmap data only take the new tensor after update()
    return leaves


def pass_leaves(loaded: LoadedScene, keys: set[str]) -> dict[str, Any]:
    """The leaves a backward pass over ``keys`` differentiates, their gradients zero.

    Those of the previous backward pass when it had the same keys (every prb pass of a run but
    the first), which skips the update; they give the same bits (tests/test_gradients.py).
    Anything else that writes the scene's parameters (:func:`enable_gradients`,
    ``loading.assign``) drops them.
    """
    import drjit as dr

    wanted = frozenset(keys)
    if loaded.held_leaves is not None and loaded.held_leaves[0] == wanted:
        leaves = loaded.held_leaves[1]
        for key in wanted:
            dr.clear_grad(leaves[key])
        return leaves
    leaves = enable_gradients(loaded, keys)
    loaded.held_leaves = (wanted, leaves)
    return leaves
