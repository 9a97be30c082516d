"""The demo's scene story: a procedural scene becomes a bundle, a viewer and a real trace make an
instance, schedulers pick chunks, and the viewer's picture at a few seconds shows what each one bought.

Kept small so that it runs in well under a minute: a 12k-splat room, the ``sort`` variant (layers
are significance-ordered prefixes; training them is the trainer's quick benchmark), 160x120 views.
The trace is scaled so that the whole scene takes about 12 s to deliver: the interesting regime,
where a scheduler has to choose.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

__all__ = ["scene_story", "online_story"]

SLOTS = 16
SHOW_AT = (2, 5, 10)  # slots whose end the pictures show


def _held_scene(bundle, held_levels: np.ndarray, objects: list[int]):
    """The splats a client holding ``held_levels[j]`` layers of object ``objects[j]`` can show."""
    full = bundle.scene(bundle.num_levels - 1)
    levels = np.zeros(int(max(objects)) + 1, np.int64)
    levels[objects] = held_levels
    ids = full.object_ids if full.object_ids is not None else np.zeros(full.num_splats, np.int64)
    return full.subset(np.nonzero(full.layers < levels[ids])[0])


def scene_story(out_dir: Path, *, time_limit_s: float = 10.0) -> dict:
    """Run the story, print a table and write ``scene-story.png``; returns the figures printed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from l3gs_opt.methods import solve
    from l3gs_opt.scene.bundle import read_bundle
    from l3gs_opt.scene.camera_paths import intrinsics_from_fov, orbit_path
    from l3gs_opt.scene.cameras import Camera
    from l3gs_opt.problem.instance import Options
    from l3gs_opt.problem.instance_io import save_instance
    from l3gs_opt.traces.poses import synthetic_poses, write_pose_log
    from l3gs_opt.renderer.metrics import ssim
    from l3gs_opt.renderer.render import render_scene
    from l3gs_opt.pipeline.build import QUICK, build_bundle
    from l3gs_opt.pipeline.scene_instance import Z_UP_MAPPING, instance_from_bundle
    from l3gs_opt.scene.procedural import make_scene

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    teacher = make_scene(12_000, objects=4, sh_degree=1, seed=0)
    train_cams = orbit_path(12, width=160, height=120)
    bundle_dir = out_dir / "bundle"
    build_bundle(teacher, train_cams, [1500, 3000, 6000, 12_000], "sort", bundle_dir, schedule=QUICK,
                 show_progress=False)
    bundle = read_bundle(bundle_dir)
    total = sum(c["bytes"] for c in bundle.manifest["chunks"])
    mbps = total * 8 / 1e6 / 12.0  # the whole scene in ~12 s at the trace's mean
    log = write_pose_log(synthetic_poses("orbit", seconds=SLOTS + 1, rate_hz=30, seed=0), out_dir / "viewer.log")
    # One link whose unspent bytes carry over: the room's chunks are larger than a second's bytes.
    inst = instance_from_bundle(bundle_dir, log, "lumos-throughput-mid-11", mbps=mbps, start=0, slots=SLOTS,
                                width=160, height=120, samples_per_slot=2, options=Options(budget="cumulative"))
    save_instance(inst, out_dir / "scene-instance.json")
    print(f"3. scene -> schedule -> picture: {teacher.num_splats} splats in {inst.J} objects x {inst.L} layers, "
          f"{total} bytes; trace mid-11 scaled to {mbps:.2f} Mbit/s (the scene in ~12 s), {SLOTS} slots, "
          "cumulative budget")
    methods = ["ilp", "rolling:bb", "slope", "static"]
    sols = {m: solve(inst, m, time_limit_s=time_limit_s) for m in methods}
    objects = inst.meta["objects"]
    intr = intrinsics_from_fov(160, 120, 70.0)
    poses = synthetic_poses("orbit", seconds=SLOTS + 1, rate_hz=30, seed=0)
    figures: dict = {"mbps": mbps, "methods": {}}
    fig, axes = plt.subplots(len(methods) + 1, len(SHOW_AT), figsize=(2.3 * len(SHOW_AT), 1.9 * (len(methods) + 1)))
    for c, t in enumerate(SHOW_AT):
        idx = min(int((t + 1) * 30) - 1, len(poses.time_s) - 1)
        w2c = Z_UP_MAPPING.world_to_camera(poses.position[idx:idx + 1], poses.rotation_deg[idx:idx + 1])[0]
        cam = Camera(**intr, world_to_camera=w2c)
        truth = np.clip(render_scene(teacher, cam).image.numpy(), 0, 1)
        axes[0, c].imshow(np.clip(truth, 0, 1))
        axes[0, c].set_title(f"full scene, end of slot {t}", fontsize=7)
        for r, m in enumerate(methods, start=1):
            held = np.zeros(inst.J, np.int64)
            for j, level, slot in sols[m].arrivals:
                if slot <= t:
                    held[j] = max(held[j], level + 1)
            shown = _held_scene(bundle, held, objects)
            img = (np.clip(render_scene(shown, cam).image.numpy(), 0, 1) if shown.num_splats
                   else np.zeros_like(truth))
            score = float(ssim(img, truth))
            figures["methods"].setdefault(m, {})[t] = score
            axes[r, c].imshow(np.clip(img, 0, 1))
            axes[r, c].set_title(f"{m}: SSIM {score:.3f}", fontsize=7)
    for ax in axes.ravel():
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out_dir / "scene-story.png", dpi=110)
    plt.close(fig)
    print(f"  {'method':<12} {'status':<10} {'utility':>12} {'bound':>12} {'time s':>7}  "
          + "  ".join(f"SSIM@{t}s" for t in SHOW_AT))
    for m in methods:
        s = sols[m]
        bound = "-" if s.bound is None else f"{s.bound:.6g}"
        print(f"  {m:<12} {s.status.value:<10} {s.objective:>12.6g} {bound:>12} {s.runtime_s:>7.2f}  "
              + "  ".join(f"{figures['methods'][m][t]:>8.3f}" for t in SHOW_AT))
        figures["methods"][m]["objective"] = s.objective
    print(f"  pictures: {out_dir / 'scene-story.png'}\n")
    figures["online"] = online_story(out_dir, bundle_dir, log, teacher, mbps)
    return figures


#: Methods of the online story: the paper's scheduler, a planner that values the future, the
#: significance-order baseline and the preloaded full model (the ceiling).
#: (method, splat utility, what the slot's last chunk counts): l3gs by the paper's Eq. 1 and by
#: visibility, the latter also counting the first splats of the chunk a slot's bytes end inside
#: (``SimConfig.last_chunk``), whole-scene layers by visibility, and the two references.
ONLINE_METHODS = (("l3gs", "eq1", "whole"), ("l3gs", "visibility", "whole"), ("l3gs", "visibility", "prefix"),
                  ("l3gs-noseg", "visibility", "whole"), ("sort", "eq1", "whole"), ("preload", "eq1", "whole"))


def online_story(out_dir: Path, bundle_dir: Path, log: Path, teacher, mbps: float) -> dict:
    """The same bundle, viewer and trace through the trace-driven simulator: each second the
    client predicts its viewport and bandwidth, a scheduler requests chunks, the link streams their
    splats in utility order, and the client's picture is scored against the full scene. Writes
    ``online-ssim.png`` and one JSON line per slot per method under ``online/``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from l3gs_opt.pipeline.scene_instance import Z_UP_MAPPING
    from l3gs_opt.simulator.simulation import SimConfig, simulate, trace_bytes

    bandwidth, _ = trace_bytes("lumos-throughput-mid-11", mbps=mbps, start=0, slots=SLOTS)
    config = SimConfig(width=160, height=120)
    print(f"4. online delivery: the simulator over the same {SLOTS} s (lr viewport and harmonic-mean bandwidth "
          "predictors, per-slot budget, splats streamed in utility order)")
    results = {}
    for m, u, last in ONLINE_METHODS:
        label = (m if u == "eq1" else f"{m}[{u}]") + ("" if last == "whole" else f" {last}")
        folder = re.sub(r"[^\w.-]+", "-", label).strip("-")   # l3gs[visibility] prefix -> l3gs-visibility-prefix
        r = simulate(bundle_dir, log, bandwidth, m, config=dataclasses.replace(config, last_chunk=last),
                     reference=teacher, mapping=Z_UP_MAPPING, out_dir=out_dir / "online" / folder, utility=u)
        results[label] = r.summary
    print(f"  {'method[utility]':<24} {'SSIM mean':>9}  SSIM per second")
    for m, s in results.items():
        print(f"  {m:<24} {s['ssim_mean']:>9.3f}  " + " ".join(f"{v:.2f}" for v in s["ssim_per_s"]))
    fig, ax = plt.subplots(figsize=(6.4, 3.2))
    for m, s in results.items():
        ax.plot(np.arange(1, len(s["ssim_per_s"]) + 1), s["ssim_per_s"], marker=".", label=f"{m} ({s['ssim_mean']:.3f})")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("SSIM vs the full scene")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(out_dir / "online-ssim.png", dpi=110)
    plt.close(fig)
    print(f"  plot: {out_dir / 'online-ssim.png'}\n")
    return {m: {"ssim_mean": s["ssim_mean"], "ssim_per_s": s["ssim_per_s"]} for m, s in results.items()}
