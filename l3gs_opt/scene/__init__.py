"""Splat scenes: the scene type and PLY files, cameras and camera paths, procedural scenes, segmentation, bundles.

Bottom layer: imports only ``l3gs_opt.errors``, ``l3gs_opt.input_files`` and ``l3gs_opt.traces.bandwidth``.
"""
