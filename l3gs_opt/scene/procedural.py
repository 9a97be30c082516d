"""Procedural multi-object teacher scenes (the stand-in for Mip-NeRF 360 / Tanks and Temples).

A room (floor, four walls and a ceiling: object id 0) holds ``objects`` distinct solids
(sphere, box, cylinder, torus, cone, ... : ids 1..objects) standing on the floor around the
room's centre. With ``room_parts`` the six room surfaces are objects of their own (ids 0..5:
floor, ceiling, walls y=-a, y=+a, x=-a, x=+a; the solids 6..5+objects): the same splats, a finer
segmentation, as a real scene's segmenter gives (walls and floor are separate segments there
too), so that no chunk holds most of the scene's bytes.  Every surface is covered by flat, overlapping, nearly opaque splats oriented
along the surface (normal axis 15 % of the tangent axes), textured with checkers, stripes and
dots, and given view-dependent colour: SH degree 1 brightens surfaces seen head-on
(``k * dot(view, -normal)``) and degrees 2-3 add small per-splat sheen.  Objects get
``OBJECT_DENSITY`` times the splat density of the room, so most splats are object detail and
dropping splats opens visible holes (SSIM falls).  World units are metres, z is up, the floor
is ``z = 0`` and the room spans ``[-ROOM_HALF, ROOM_HALF]^2 x [0, ROOM_HEIGHT]``.

Deterministic: the same arguments give the same scene bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

from l3gs_opt.scene.splats import SceneError, SplatScene, check_seed, check_sh_degree

__all__ = ["make_scene", "ROOM_HALF", "ROOM_HEIGHT", "OBJECT_DENSITY", "SHAPES", "MIN_SPLATS", "MAX_SPLATS", "ROOM_PARTS"]

ROOM_HALF = 4.0
ROOM_HEIGHT = 3.0
#: Objects the room becomes with ``room_parts``: floor, ceiling and four walls.
ROOM_PARTS = 6
#: Splats per square metre on objects relative to the room's surfaces.
OBJECT_DENSITY = 12.0
SHAPES = ("sphere", "box", "cylinder", "torus", "cone")
MIN_SPLATS = 1_000
MAX_SPLATS = 2_000_000
_SH_C0 = 0.28209479177387814
_SH_C1 = 0.4886025119029199


# ------------------------------------------------------------------ surface samplers
# Each returns (points [m, 3], normals [m, 3], uv [m, 2]) for m uniform samples on the surface,
# and each has an area function.  Shapes are centred on the origin, resting on z = 0.

def _sphere(rng, m, s):
    n = rng.normal(size=(m, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    uv = np.stack([np.arctan2(n[:, 1], n[:, 0]) / (2 * np.pi) + 0.5, np.arccos(np.clip(n[:, 2], -1, 1)) / np.pi], 1)
    return n * s + [0, 0, s], n, uv


def _sphere_area(s):
    return 4 * np.pi * s * s


def _box(rng, m, s):
    half = np.array([s, 0.7 * s, 0.8 * s])
    areas = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]]).repeat(2) * 4
    face = rng.choice(6, size=m, p=areas / areas.sum())
    axis, sign = face // 2, np.where(face % 2 == 0, 1.0, -1.0)
    uvw = rng.uniform(-1, 1, size=(m, 3)) * half
    uvw[np.arange(m), axis] = sign * half[axis]
    normals = np.zeros((m, 3))
    normals[np.arange(m), axis] = sign
    others = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    uv = (uvw[np.arange(m)[:, None], others] / half[others] + 1) / 2
    return uvw + [0, 0, half[2]], normals, uv


def _box_area(s):
    h = np.array([s, 0.7 * s, 0.8 * s])
    return 8 * (h[0] * h[1] + h[0] * h[2] + h[1] * h[2])


def _cylinder(rng, m, s):
    r, h = 0.6 * s, 2.0 * s
    side, cap = 2 * np.pi * r * h, np.pi * r * r
    kind = rng.choice(3, size=m, p=np.array([side, cap, cap]) / (side + 2 * cap))
    th = rng.uniform(0, 2 * np.pi, m)
    z = rng.uniform(0, h, m)
    rad = r * np.sqrt(rng.uniform(0, 1, m))
    pts = np.where(kind[:, None] == 0, np.stack([r * np.cos(th), r * np.sin(th), z], 1),
                   np.stack([rad * np.cos(th), rad * np.sin(th), np.where(kind == 1, h, 0.0)], 1))
    nrm = np.where(kind[:, None] == 0, np.stack([np.cos(th), np.sin(th), 0 * th], 1),
                   np.stack([0 * th, 0 * th, np.where(kind == 1, 1.0, -1.0)], 1))
    uv = np.stack([th / (2 * np.pi), np.where(kind == 0, z / h, rad / r)], 1)
    return pts, nrm, uv


def _cylinder_area(s):
    r, h = 0.6 * s, 2.0 * s
    return 2 * np.pi * r * h + 2 * np.pi * r * r


def _torus(rng, m, s):
    R, r = 0.8 * s, 0.3 * s
    out_u, out_v = [], []
    while sum(len(u) for u in out_u) < m:  # rejection sampling for a uniform area density
        u = rng.uniform(0, 2 * np.pi, 2 * m)
        v = rng.uniform(0, 2 * np.pi, 2 * m)
        keep = rng.uniform(0, 1, 2 * m) < (R + r * np.cos(v)) / (R + r)
        out_u.append(u[keep])
        out_v.append(v[keep])
    u = np.concatenate(out_u)[:m]
    v = np.concatenate(out_v)[:m]
    nrm = np.stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)], 1)
    ctr = np.stack([R * np.cos(u), R * np.sin(u), 0 * u], 1)
    # standing torus: rotate so that its axis is horizontal (x), then lift onto the floor
    rot = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    pts = (ctr + r * nrm) @ rot.T + [0, 0, R + r]
    return pts, nrm @ rot.T, np.stack([u / (2 * np.pi), v / (2 * np.pi)], 1)


def _torus_area(s):
    return 4 * np.pi ** 2 * (0.8 * s) * (0.3 * s)


def _cone(rng, m, s):
    r, h = 0.8 * s, 2.2 * s
    slant = math.hypot(r, h)
    side, base = np.pi * r * slant, np.pi * r * r
    kind = rng.choice(2, size=m, p=[side / (side + base), base / (side + base)])
    th = rng.uniform(0, 2 * np.pi, m)
    f = np.sqrt(rng.uniform(0, 1, m))  # distance from the apex (side) / centre (base), area-uniform
    side_pts = np.stack([f * r * np.cos(th), f * r * np.sin(th), h * (1 - f)], 1)
    base_pts = np.stack([f * r * np.cos(th), f * r * np.sin(th), 0 * th], 1)
    ns = np.stack([h * np.cos(th), h * np.sin(th), r * np.ones_like(th)], 1) / slant
    nb = np.stack([0 * th, 0 * th, -np.ones_like(th)], 1)
    pts = np.where(kind[:, None] == 0, side_pts, base_pts)
    nrm = np.where(kind[:, None] == 0, ns, nb)
    return pts, nrm, np.stack([th / (2 * np.pi), f], 1)


def _cone_area(s):
    r, h = 0.8 * s, 2.2 * s
    return np.pi * r * math.hypot(r, h) + np.pi * r * r


_SAMPLERS = {"sphere": (_sphere, _sphere_area), "box": (_box, _box_area),
             "cylinder": (_cylinder, _cylinder_area), "torus": (_torus, _torus_area),
             "cone": (_cone, _cone_area)}


def _room(rng, m):
    """Floor, walls and ceiling of the room; normals point inwards."""
    a, h = ROOM_HALF, ROOM_HEIGHT
    # (origin, edge u, edge v, normal)
    faces = [((-a, -a, 0), (2 * a, 0, 0), (0, 2 * a, 0), (0, 0, 1)),          # floor
             ((-a, -a, h), (2 * a, 0, 0), (0, 2 * a, 0), (0, 0, -1)),         # ceiling
             ((-a, -a, 0), (2 * a, 0, 0), (0, 0, h), (0, 1, 0)),              # wall y = -a
             ((-a, a, 0), (2 * a, 0, 0), (0, 0, h), (0, -1, 0)),              # wall y = +a
             ((-a, -a, 0), (0, 2 * a, 0), (0, 0, h), (1, 0, 0)),              # wall x = -a
             ((a, -a, 0), (0, 2 * a, 0), (0, 0, h), (-1, 0, 0))]              # wall x = +a
    areas = np.array([np.linalg.norm(np.cross(f[1], f[2])) for f in faces])
    face = rng.choice(6, size=m, p=areas / areas.sum())
    uv = rng.uniform(0, 1, size=(m, 2))
    o, eu, ev, nn = (np.array([f[k] for f in faces], float)[face] for k in range(4))
    pts = o + uv[:, :1] * eu + uv[:, 1:] * ev
    return pts, nn, uv, face


def _texture(kind: int, uv: np.ndarray, freq: float) -> np.ndarray:
    """Pattern value in [0, 1] per sample (0 = colour A, 1 = colour B)."""
    u, v = uv[:, 0] * freq, uv[:, 1] * freq
    if kind == 0:   # checker
        return ((np.floor(u) + np.floor(v)) % 2).astype(float)
    if kind == 1:   # stripes
        return (np.sin(2 * np.pi * (u + 0.5 * v)) > 0).astype(float)
    if kind == 2:   # dots
        return ((np.hypot(u % 1 - 0.5, v % 1 - 0.5) < 0.3)).astype(float)
    return 0.5 + 0.5 * np.sin(2 * np.pi * u) * np.cos(2 * np.pi * v)  # smooth waves


def _frames_to_quats(normals: np.ndarray, rng) -> np.ndarray:
    """Quaternions (w, x, y, z) of frames whose third axis is the normal (random spin about it)."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    a = np.where(np.abs(n[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    t1 = np.cross(n, a)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    phi = rng.uniform(0, 2 * np.pi, len(n))[:, None]
    t1, t2 = np.cos(phi) * t1 + np.sin(phi) * t2, -np.sin(phi) * t1 + np.cos(phi) * t2
    R = np.stack([t1, t2, n], axis=2)  # columns
    # rotation matrix -> quaternion (Shepperd, vectorised)
    tr = R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2]
    q = np.empty((len(n), 4))
    c0 = tr > 0
    c1 = ~c0 & (R[:, 0, 0] >= R[:, 1, 1]) & (R[:, 0, 0] >= R[:, 2, 2])
    c2 = ~c0 & ~c1 & (R[:, 1, 1] >= R[:, 2, 2])
    c3 = ~(c0 | c1 | c2)
    s = np.sqrt(np.maximum(tr + 1, 1e-12)) * 2
    q[c0] = np.stack([0.25 * s, (R[:, 2, 1] - R[:, 1, 2]) / s, (R[:, 0, 2] - R[:, 2, 0]) / s,
                      (R[:, 1, 0] - R[:, 0, 1]) / s], 1)[c0]
    s = np.sqrt(np.maximum(1 + R[:, 0, 0] - R[:, 1, 1] - R[:, 2, 2], 1e-12)) * 2
    q[c1] = np.stack([(R[:, 2, 1] - R[:, 1, 2]) / s, 0.25 * s, (R[:, 0, 1] + R[:, 1, 0]) / s,
                      (R[:, 0, 2] + R[:, 2, 0]) / s], 1)[c1]
    s = np.sqrt(np.maximum(1 + R[:, 1, 1] - R[:, 0, 0] - R[:, 2, 2], 1e-12)) * 2
    q[c2] = np.stack([(R[:, 0, 2] - R[:, 2, 0]) / s, (R[:, 0, 1] + R[:, 1, 0]) / s, 0.25 * s,
                      (R[:, 1, 2] + R[:, 2, 1]) / s], 1)[c2]
    s = np.sqrt(np.maximum(1 + R[:, 2, 2] - R[:, 0, 0] - R[:, 1, 1], 1e-12)) * 2
    q[c3] = np.stack([(R[:, 1, 0] - R[:, 0, 1]) / s, (R[:, 0, 2] + R[:, 2, 0]) / s,
                      (R[:, 1, 2] + R[:, 2, 1]) / s, 0.25 * s], 1)[c3]
    return q


def make_scene(num_splats: int = 100_000, *, objects: int = 5, sh_degree: int = 3,
               seed: int = 0, room_parts: bool = False) -> SplatScene:
    """Build a procedural room with ``objects`` textured solids (see the module docstring).

    Parameters
    ----------
    num_splats : int
        Total splats, ``MIN_SPLATS``..``MAX_SPLATS`` (about 10k to 1M is the intended range).
    objects : int, keyword-only
        Number of objects on the floor, 1..12 (ids 1..objects; the room is id 0).
    sh_degree : int, keyword-only
        0..3.  Degree 0 drops the view dependence.
    seed : int, keyword-only
        Seed of every random choice (layout, colours, sampling), >= 0.
    room_parts : bool, keyword-only
        Give the room's six surfaces their own object ids (see the module docstring); the splats
        are identical either way.

    Returns
    -------
    SplatScene
        With ``object_ids``; a single layer.

    Raises
    ------
    SceneError
        On an argument out of range or of the wrong type (a bool or float ``sh_degree``, a
        ``room_parts`` that is not a bool).
    """
    if isinstance(num_splats, bool) or not isinstance(num_splats, (int, np.integer)) or \
            not MIN_SPLATS <= num_splats <= MAX_SPLATS:
        raise SceneError("num_splats", f"{num_splats!r}: must be an integer in [{MIN_SPLATS}, {MAX_SPLATS}]")
    if isinstance(objects, bool) or not isinstance(objects, (int, np.integer)) or not 1 <= objects <= 12:
        raise SceneError("objects", f"{objects!r}: must be an integer in [1, 12]")
    sh_degree = check_sh_degree(sh_degree)
    # A flag, not a truthy value: "no" would otherwise split the room.
    if not isinstance(room_parts, (bool, np.bool_)):
        raise SceneError("room_parts", f"{room_parts!r}: must be true or false")
    rng = np.random.default_rng(check_seed(seed))
    # --- layout: objects on a ring around the centre, random size, colours, pattern
    specs = []
    ring = 1.9
    for j in range(objects):
        ang = 2 * np.pi * j / objects + rng.uniform(-0.2, 0.2)
        rad = ring + rng.uniform(-0.3, 0.3) if objects > 1 else 0.0
        shape = SHAPES[j % len(SHAPES)]
        size = rng.uniform(0.35, 0.6)
        col_a = rng.uniform(0.05, 0.95, 3)
        col_b = np.clip(1.0 - col_a + rng.uniform(-0.2, 0.2, 3), 0.02, 0.98)
        specs.append(dict(shape=shape, size=size, pos=np.array([rad * np.cos(ang), rad * np.sin(ang), 0.0]),
                          yaw=rng.uniform(0, 2 * np.pi), col_a=col_a, col_b=col_b,
                          pattern=int(rng.integers(0, 4)), freq=float(rng.uniform(3, 8)),
                          shine=float(rng.uniform(0.1, 0.35))))
    room_area = 2 * (2 * ROOM_HALF) ** 2 + 4 * (2 * ROOM_HALF) * ROOM_HEIGHT
    obj_areas = np.array([_SAMPLERS[s["shape"]][1](s["size"]) for s in specs])
    w = np.concatenate([[room_area], OBJECT_DENSITY * obj_areas])
    counts = np.floor(w / w.sum() * num_splats).astype(int)
    counts[0] += num_splats - counts.sum()
    areas = np.concatenate([[room_area], obj_areas])

    pts_l, nrm_l, rgb_l, oid_l, spacing_l, shine_l = [], [], [], [], [], []
    # --- room
    p, nn, uv, face = _room(rng, counts[0])
    room_cols = np.array([[0.55, 0.38, 0.22], [0.92, 0.92, 0.88], [0.75, 0.55, 0.45],
                          [0.45, 0.6, 0.75], [0.6, 0.7, 0.5], [0.8, 0.75, 0.5]])
    base = room_cols[face]
    floor = face == 0
    tex = np.where(floor, _texture(0, uv, 8.0), _texture(1, uv, 6.0))
    tex = np.where(face == 1, 0.0, tex)
    rgb = base * (0.75 + 0.35 * tex[:, None])
    rgb += rng.normal(0, 0.03, rgb.shape)
    pts_l.append(p); nrm_l.append(nn); rgb_l.append(rgb)
    oid_l.append(face.astype(int) if room_parts else np.zeros(len(p), int))
    first = ROOM_PARTS if room_parts else 1
    spacing_l.append(np.full(len(p), math.sqrt(areas[0] / max(counts[0], 1))))
    shine_l.append(np.full(len(p), 0.08))
    # --- objects
    for j, s in enumerate(specs):
        m = counts[j + 1]
        fn = _SAMPLERS[s["shape"]][0]
        p, nn, uv = fn(rng, m, s["size"])
        c, sn = math.cos(s["yaw"]), math.sin(s["yaw"])
        rz = np.array([[c, -sn, 0], [sn, c, 0], [0, 0, 1]])
        p = p @ rz.T + s["pos"]
        nn = nn @ rz.T
        t = _texture(s["pattern"], uv, s["freq"])[:, None]
        rgb = s["col_a"] * (1 - t) + s["col_b"] * t + rng.normal(0, 0.02, (m, 3))
        pts_l.append(p); nrm_l.append(nn); rgb_l.append(rgb); oid_l.append(np.full(m, first + j))
        spacing_l.append(np.full(m, math.sqrt(areas[j + 1] / max(m, 1))))
        shine_l.append(np.full(m, s["shine"]))
    pts = np.concatenate(pts_l)
    nrm = np.concatenate(nrm_l)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    rgb = np.clip(np.concatenate(rgb_l), 0.0, 1.0)
    oid = np.concatenate(oid_l)
    spacing = np.concatenate(spacing_l)
    shine = np.concatenate(shine_l)
    n = len(pts)
    # --- splat shape: flat discs a bit larger than the sample spacing, nearly opaque
    tang = spacing * 0.85
    scales = np.stack([tang * rng.uniform(0.8, 1.25, n), tang * rng.uniform(0.8, 1.25, n),
                       0.15 * tang], axis=1)
    quats = _frames_to_quats(nrm, rng)
    logits = rng.uniform(2.0, 4.0, n)
    # --- colour: DC gives rgb * 0.8 on average; degree 1 adds shine * dot(view, -normal)
    k = (sh_degree + 1) ** 2
    sh = np.zeros((n, k, 3))
    sh[:, 0] = (0.85 * rgb - 0.5) / _SH_C0
    if sh_degree >= 1:
        v = -nrm * shine[:, None]  # colour += shine * dot(d, -n) * (rgb + 0.3)
        tint = rgb + 0.3
        sh[:, 1] = (-v[:, 1] / _SH_C1)[:, None] * tint
        sh[:, 2] = (v[:, 2] / _SH_C1)[:, None] * tint
        sh[:, 3] = (-v[:, 0] / _SH_C1)[:, None] * tint
    if sh_degree >= 2:
        sh[:, 4:] = rng.normal(0, 0.04, (n, k - 4, 3)) * (shine[:, None, None] / 0.2)
    perm = rng.permutation(n)  # interleave objects, as trained scenes are
    return SplatScene(means=pts[perm], log_scales=np.log(scales[perm]), quats=quats[perm],
                      opacity_logits=logits[perm], sh=sh[perm], object_ids=oid[perm])
