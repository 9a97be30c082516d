"""Several clients on one bottleneck: each its own viewer and method, one trace, max-min fair shares.

Every part of every slot (``SimConfig.substeps`` parts per slot), each client plans as if alone
and asks for what its link would move (:meth:`l3gs_opt.simulator.link.Link.demand`: the chunk in flight
plus its requests, beyond its bank); the part's bytes are split max-min fairly among these
demands (:func:`l3gs_opt.simulator.link.max_min_shares`: bytes a client cannot use go to the others, and
the shares always sum to the trace's bytes). A client predicts its bandwidth from the shares it
got in earlier slots; before it has any (slot 0) and with the ``oracle`` predictor it assumes an
equal share of the trace. With one client this is :meth:`Simulation.run` exactly.
"""

from __future__ import annotations

import os
from typing import Sequence

from l3gs_opt.simulator.config import SimConfig, SimulationError

__all__ = ["run_shared", "simulate_shared"]


def run_shared(simulations: Sequence, methods: Sequence, *, solvers: Sequence | None = None,
               out_dir: str | os.PathLike | None = None, progress: bool = False) -> list:
    """Run client i = ``methods[i]`` on ``simulations[i]``, all sharing one bottleneck.

    Parameters
    ----------
    simulations : sequence of Simulation, K of them
        Each client's bundle, viewer and config; all must have the same bandwidth (the shared
        trace, bytes per slot), slot length and parts per slot. One simulation may serve several
        clients (its predictions and renders are shared, the client state is not).
    methods : sequence of str or MethodSpec, K of them
    solvers : sequence of str or None, optional
        Per client, as ``solver`` of :meth:`Simulation.run`.
    out_dir : path, optional
        Records as :meth:`Simulation.run` writes them, tagged ``client`` (its index).

    Returns
    -------
    list of SimulationResult
        One per client; every record and summary carries ``client``, ``clients`` and
        ``bytes_share`` (the bytes of the bottleneck it got; ``bytes_trace`` is the whole trace's).

    Raises
    ------
    SimulationError
        No client, lengths that differ, simulations on different traces or slot grids.
    """
    from l3gs_opt.simulator.client import Client, drive

    sims, methods = list(simulations), list(methods)
    if not sims:
        raise SimulationError("simulations", "at least one client is needed")
    if len(methods) != len(sims):
        raise SimulationError("methods", f"{len(methods)} methods for {len(sims)} simulations")
    solvers = [None] * len(sims) if solvers is None else list(solvers)
    if len(solvers) != len(sims):
        raise SimulationError("solvers", f"{len(solvers)} solvers for {len(sims)} simulations")
    first = sims[0]
    for i, sim in enumerate(sims):
        if sim.link_bytes != first.link_bytes:
            raise SimulationError("simulations", "its bandwidth differs from client 0's: the clients share one "
                                                 "trace", i)
        if (sim.config.slot_s, sim.config.substeps) != (first.config.slot_s, first.config.substeps):
            raise SimulationError("simulations", "slot_s and substeps must equal client 0's (one clock)", i)
    K = len(sims)
    clients = [Client(sim, sim.spec(m, s), index=i, clients=K, out_dir=out_dir)
               for i, (sim, m, s) in enumerate(zip(sims, methods, solvers))]
    drive(clients, first.link_bytes, progress=progress)
    return [c.finish() for c in clients]


def simulate_shared(bundle, poses: Sequence, bandwidth_bytes: Sequence[int], methods: Sequence, *,
                    solvers: Sequence | None = None, config: SimConfig = SimConfig(), reference=None, mapping=None,
                    out_dir=None, progress: bool = False, cache_dir=None) -> list:
    """K clients, each its own pose log and method, fetching ``bundle`` over one trace (see :func:`run_shared`).

    ``bundle`` is one bundle for all or a sequence of K; ``poses[i]`` is client i's viewer
    (paths or PoseTraces; the same object or path twice shares one :class:`Simulation`).

    Example
    -------
    >>> rs = simulate_shared("bundle/", ["a.log", "b.log"], bw, ["l3gs", "sort"])   # doctest: +SKIP
    >>> [r.summary["bytes_share"] for r in rs]                                      # doctest: +SKIP
    """
    from l3gs_opt.simulator.simulation import Simulation

    poses = list(poses)
    K = len(poses)
    bundles = list(bundle) if isinstance(bundle, (list, tuple)) else [bundle] * K
    if len(bundles) != K:
        raise SimulationError("bundle", f"{len(bundles)} bundles for {K} clients")
    made: dict = {}
    sims = []
    for b, p in zip(bundles, poses):
        key = (b if isinstance(b, (str, os.PathLike)) else id(b), p if isinstance(p, (str, os.PathLike)) else id(p))
        key = tuple(str(k) if isinstance(k, os.PathLike) else k for k in key)
        if key not in made:
            made[key] = Simulation(b, p, bandwidth_bytes, config=config, reference=reference, mapping=mapping,
                                   cache_dir=cache_dir)
        sims.append(made[key])
    return run_shared(sims, methods, solvers=solvers, out_dir=out_dir, progress=progress)
