"""The trace-driven delivery simulation: link model, client, catalogue, schedulers, records, shared link.
"""
