"""Small seeded instances shared by the core tests: every representation and option."""

from __future__ import annotations

import itertools

import numpy as np

from l3gs_opt import Instance, Options

ALL_OPTIONS = [Options(availability=a, same_slot_layers=s, budget=b)
               for a, s, b in itertools.product(("same_slot", "next_slot"), (True, False), ("per_slot", "cumulative"))]
#: The options with a per-slot budget (what ``exact`` and the level-keeping repair accept).
PER_SLOT_OPTIONS = [o for o in ALL_OPTIONS if o.budget == "per_slot"]


def option_id(o: Options) -> str:
    return f"{o.availability}-{'same' if o.same_slot_layers else 'strict'}-{o.budget}"


def random_instance(rng: np.random.Generator, *, representation: str = "layered", T: int = 3, J: int = 2,
                    L: int = 2, options: Options | None = None, held_p: float = 0.0, zero_p: float = 0.2,
                    cost_range: tuple[int, int] = (1, 6), tight: float = 0.6) -> Instance:
    """Random instance with some zero utilities and a budget that binds (``tight`` x mean cost)."""
    cost = rng.integers(cost_range[0], cost_range[1] + 1, size=(J, L))
    utility = rng.random((T, J, L)) * (rng.random((T, J, L)) > zero_p)
    mean_total = cost.sum() / max(T, 1)
    bandwidth = rng.integers(0, max(1, int(2 * tight * mean_total)) + 1, size=T)
    held = np.zeros((J, L), dtype=bool)
    if held_p > 0:
        for j in range(J):
            if representation == "layered":
                held[j, : int(rng.binomial(L, held_p))] = True
            else:
                held[j] = rng.random(L) < held_p
    return Instance(representation, bandwidth=bandwidth, cost=cost, utility=utility, held=held,
                    options=options or Options())
