"""Counts given by a user (viewpoints per slot, parts of a slot, grid sizes): one check with an upper
limit, so that a mistyped ``--samples-per-slot 100000000`` is refused by name before any work
instead of running for days or exhausting memory.

The limits are far above any useful setting and well below what takes hours on a laptop; each
states why it is where it is.
"""

from __future__ import annotations

# The check itself is shared by every layer (the traces check their counts the same way).
from l3gs_opt.checks import ArgumentError as CountError
from l3gs_opt.checks import check_count

__all__ = ["CountError", "check_count", "MAX_SAMPLES_PER_SLOT", "MAX_SUBSTEPS", "MAX_YAW_STEPS",
           "MAX_GRID_POSITIONS", "MAX_FIDELITY_SAMPLES"]

#: Viewpoints per slot: each is one utility evaluation (and render) per slot; 1000 is a sample every
#: millisecond of a 1 s slot, finer than any pose log.
MAX_SAMPLES_PER_SLOT = 1000
#: Parts of a slot, each a re-plan of every client: 1000 is a part per millisecond of a 1 s slot.
MAX_SUBSTEPS = 1000
#: Yaws of a utility table: 3600 is one every 0.1 degree, far below what interpolation needs.
MAX_YAW_STEPS = 3600
#: Positions of a utility table grid (NX * NY * NZ): each costs ``yaw_steps * len(pitches)``
#: viewpoint evaluations; 100000 (e.g. 46^3) already takes hours and its table gigabytes.
MAX_GRID_POSITIONS = 100_000
#: Sampled (slot, held state) pairs of a fidelity run: each renders the picture of every candidate
#: chunk (144 on the 180k-splat room, ``benchmarks/results/utility_fidelity``, which used 8 and 16);
#: 10000 is days of rendering already.
MAX_FIDELITY_SAMPLES = 10_000
