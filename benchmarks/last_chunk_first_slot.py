"""The first slot of the 20k room, orbit, window lumos-throughput-high-31@397: what the slot's
bytes buy as whole chunks (every precedence-closed set of at most four chunks that fit, enumerated)
against the first splats of one chunk (each chunk's splats in descending predicted value, as the
link streams them). Independent of :mod:`l3gs_opt.simulator.last_chunk`: plain enumeration.

    .venv/bin/python benchmarks/last_chunk_first_slot.py CACHE [UTILITY] [CONDITION]

``CACHE`` holds ``room20k-o8-parts/`` as ``bench_last_chunk.py --cache`` builds it.
"""
import itertools
import sys

import numpy as np
from l3gs_opt.experiments.plan import ABLATIONS, scaled_mbps
from l3gs_opt.simulator.simulation import Simulation, SimConfig, trace_bytes
from l3gs_opt.scene.bundle import read_bundle
from l3gs_opt.traces.poses import synthetic_poses

cache = sys.argv[1].rstrip('/') + '/room20k-o8-parts'
bundle = read_bundle(cache + '/layered')
scene_bytes = int(sum(c["bytes"] for c in bundle.manifest["chunks"]))
bw, info = trace_bytes('lumos-throughput-high-31', mbps=scaled_mbps(scene_bytes), start=397, slots=8)
poses = synthetic_poses('orbit', seconds=62, rate_hz=30, seed=0)
util = sys.argv[2] if len(sys.argv) > 2 else 'visibility'
abl = sys.argv[3] if len(sys.argv) > 3 else 'none'
sim = Simulation(bundle, poses, bw, config=SimConfig(width=160, height=120, samples_per_slot=2, **ABLATIONS[abl]), info=info)
cat = sim.catalog('object')
J, L = cat.shape
u = sim.splat_values(0, util)
C = int(bw[0])
units = {}
for k in range(J * L):
    j, l = divmod(k, L)
    rows = cat.rows[k]
    if len(rows) == 0:
        continue
    v = np.sort(u[rows])[::-1]
    bps = int(cat.bytes_per_splat[k])
    units[(j, l)] = (int(cat.bytes[k]), float(v.sum()), np.concatenate([[0.0], np.cumsum(v)]), bps)
empty = {(j, l) for j in range(J) for l in range(L) if (j, l) not in units}
print('capacity', C, 'bytes/splat', {u_[3] for u_ in units.values()})
print('layer-0 chunk bytes:', sorted((units[(j,0)][0], j) for j in range(J) if (j,0) in units))
# value per unit at t=0 (whole)
top = sorted(units.items(), key=lambda kv: -kv[1][1] / kv[1][0])[:12]
for (j, l), (b, val, pre, bps) in top:
    print(f'  unit {(j,l)} bytes {b} value {val:.1f} per kB {1000*val/b:.2f}  prefix within C: {pre[min(len(pre)-1, C // bps)]:.1f}')
# best whole-chunk set within C (prerequisites: lower non-empty layers)
def closed(S):
    return all(all((j, m) in S or (j, m) in empty for m in range(l)) for (j, l) in S)
small = [k for k, v in units.items() if v[0] <= C]
best = (0.0, ())
for r in range(1, 5):
    for S in itertools.combinations(small, r):
        if sum(units[k][0] for k in S) <= C and closed(set(S)):
            val = sum(units[k][1] for k in S)
            if val > best[0]:
                best = (val, S)
print('best whole-chunk set:', best)
bestp = max(((units[k][2][min(len(units[k][2]) - 1, C // units[k][3])], k) for k in units if k[1] == 0 or all((k[0], m) in empty for m in range(k[1]))))
print('best single partial chunk (top splats):', bestp)
