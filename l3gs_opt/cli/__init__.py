"""The ``l3gs-opt`` command line: one module per command family, and the demo.
"""
