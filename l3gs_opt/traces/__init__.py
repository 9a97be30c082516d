"""What the network and the viewer do over time: bandwidth traces, pose logs, viewport and bandwidth predictors.

Bottom layer: imports only ``l3gs_opt.errors`` and ``l3gs_opt.input_files``.
"""
