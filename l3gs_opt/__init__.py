"""l3gs-opt: optimization models and solvers for delivering layered 3D Gaussian splat scenes.

Quick start::

    import l3gs_opt
    inst = l3gs_opt.load_instance("instance.json")
    sol = l3gs_opt.solve(inst, method="ilp", backend="highs")
    print(sol.status, sol.objective, sol.bound, sol.gap)
"""

from l3gs_opt.errors import BackendUnavailableError, InstanceError, L3gsError, SolveError
from l3gs_opt.problem.instance import MAX_BYTES, SCHEMA, Instance, Options
from l3gs_opt.problem.instance_io import instance_from_dict, load_instance, save_instance
from l3gs_opt.problem.evaluate import evaluate_objective, feasibility_violations, is_feasible
from l3gs_opt.problem.solution import GAP_TOL, ModelSize, Solution, Status, relative_gap
from l3gs_opt.problem.presolve import presolve
from l3gs_opt.methods import METHODS, method_names, solve

__version__ = "0.1.0"

# The rest of the public API is imported on first use (PEP 562): the renderer-backed modules pull
# in torch, which a user who only solves instances should not wait for.
_LAZY = {
    "traces.bandwidth": ["TraceError", "BandwidthTrace", "bundled_traces", "read_bandwidth_trace", "mbps_to_bytes",
               "synthetic_bandwidth", "AmbiguousTraceError", "TRACE_FORMATS", "detect_format", "write_mahimahi"],
    "traces.eyenavgs": ["EyeNavError", "EyeNavTrace", "SceneAlignment", "read_eyenavgs", "read_scene_settings"],
    "pipeline.synth": ["synth_instance", "walking_viewer"],
    "traces.predictors": ["PredictionError", "predict_viewport", "viewport_errors", "predict_bandwidth",
                   "bandwidth_errors"],
    "traces.poses": ["PoseError", "PoseTrace", "PoseMapping", "read_pose_log", "write_pose_log", "read_camera_path",
              "write_camera_path", "synthetic_poses"],
    "pipeline.splat_utility": ["UtilityError", "UtilityScene", "splat_utility", "object_layer_utility", "UtilityTable",
                "build_utility_table", "grid_positions"],
    # Splat utilities (issue 21): the interface, the built-ins by name, and how well they predict the picture.
    "pipeline.utilities": ["SplatUtility", "UtilityNameError", "register_utility", "get_utility", "utility_names"],
    "pipeline.fidelity": ["utility_fidelity", "FidelityReport"],
    "simulator.records": ["RunSummary"],
    "executors": ["run_tasks"],
    # Compiles exact's numba kernels once per machine, off any solve's clock (scripts/setup.sh runs it).
    "solvers.exact.warm": ["warm_up"],
    "bench.run": ["BenchError", "BenchTask", "run_bench", "read_records"],
    # One strict JSON serialiser and one JSONL record writer for every output (issue 19).
    "jsonout": ["OutputError", "JsonOutputError"],
    "records": ["RecordFileError", "OutputLockedError", "RecordLog"],
    "bench.report": ["write_report"],
    "bench.suites": ["InstanceSpec", "suite_specs"],
    "scene.splats": ["SceneError", "SplatScene", "read_ply", "write_ply"],
    "scene.cameras": ["CameraError", "Camera", "load_cameras", "save_cameras", "look_at"],
    "scene.procedural": ["make_scene"],
    "scene.camera_paths": ["orbit_path", "walk_path"],
    "scene.bundle": ["BUNDLE_SCHEMA", "VARIANTS", "BundleError", "Bundle", "read_bundle", "write_bundle", "split_layers"],
    "pipeline.build": ["BuildError", "BuildSchedule", "build_bundle"],
    "scene.segment": ["segment_scene", "segment_labels", "adjusted_rand_index"],
    # Scene files by extension (.ply, .compressed.ply, .splat, .spz) and the streamable bundle (issue 22).
    "scene.scene_files": ["SCENE_FORMATS", "read_scene", "write_scene"],
    "scene.stream_index": ["StreamError", "StreamIndex", "export_stream", "read_stream", "load_stream_chunk",
                           "stream_bundle"],
    "pipeline.scene_instance": ["instance_from_bundle"],
    "simulator.link": ["LinkError", "Link", "SlotDelivery", "max_min_shares", "split_bytes"],
    "simulator.simulation": ["SimulationError", "SimConfig", "Simulation", "SimulationResult", "SIM_METHODS"],
    "experiments.plan": ["ExperimentError", "ExperimentPlan", "make_plan"],
    "experiments.run": ["run_experiments"],
    "simulator.shared": ["run_shared", "simulate_shared"],
    "simulator.last_chunk": ["LastChunkPlan", "plan_last_chunk"],
    "simulator.render": ["RenderCache"],
    # The item form (l3gs-opt/items@1): precedence DAG and replacement groups (distill, hierarchy bundles).
    "problem.items": ["ITEMS_SCHEMA", "ItemInstanceError", "ItemInstance", "items_from_instance", "instance_arrivals",
              "distill_items", "hierarchy_items"],
    "problem.items_io": ["items_from_dict", "load_items", "save_items"],
    "problem.items_eval": ["evaluate_items", "item_violations", "items_feasible"],
}
_LAZY_NAMES = {name: module for module, names in _LAZY.items() for name in names}


def __getattr__(name: str):
    module = _LAZY_NAMES.get(name)
    if module is None:
        raise AttributeError(f"module 'l3gs_opt' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY_NAMES))


__all__ = [
    "BackendUnavailableError",
    "GAP_TOL",
    "Instance",
    "InstanceError",
    "L3gsError",
    "MAX_BYTES",
    "METHODS",
    "ModelSize",
    "Options",
    "SCHEMA",
    "Solution",
    "SolveError",
    "Status",
    "evaluate_objective",
    "feasibility_violations",
    "instance_from_dict",
    "is_feasible",
    "load_instance",
    "method_names",
    "presolve",
    "relative_gap",
    "save_instance",
    "solve",
    *sorted(_LAZY_NAMES),
]
