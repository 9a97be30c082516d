"""Running the command line in process for the bad-input tests (``test_*bad_input*``,
``test_reliability_inputs``), and the tiny delivery world several of them run it on."""

from __future__ import annotations

from l3gs_opt.cli.main import main


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """Exit code, stdout and stderr of ``l3gs-opt ARGV`` (arguments made text)."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(capsys, *argv) -> str:
    """Run the CLI on bad input: exit 2 and stderr exactly one ``error:`` line (blank lines aside),
    which is returned."""
    code, _, err = run_cli(capsys, *argv)
    lines = [x for x in err.splitlines() if x.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), (code, err)
    return lines[0]


def tiny_sort_bundle(root, name: str = "ok") -> dict:
    """A 1000-splat, 2-object ``sort`` bundle of 2 layers in ``root/name`` and a 4 s orbiting pose log:
    the smallest delivery world the bad-input tests run commands on. Returns ``root``, ``bundle``,
    ``log`` and the teacher ``scene``."""
    import numpy as np

    from l3gs_opt.scene.bundle import write_bundle
    from l3gs_opt.scene.procedural import make_scene
    from l3gs_opt.traces.poses import synthetic_poses, write_pose_log

    teacher = make_scene(1000, objects=2, sh_degree=0, seed=0)
    order = np.random.default_rng(0).permutation(teacher.num_splats)
    write_bundle(root / name, [teacher.subset(order[:300]), teacher.subset(order[300:])], variant="sort")
    log = write_pose_log(synthetic_poses("orbit", seconds=4, rate_hz=30, seed=0), root / "viewer.log")
    return {"root": root, "bundle": root / name, "log": log, "scene": teacher}
