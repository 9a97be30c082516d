"""The problem forms: instances and item instances, their files, presolve, evaluation and the ``Solution``.

Bottom layer: imports only ``l3gs_opt.errors`` and ``l3gs_opt.input_files``.
"""
