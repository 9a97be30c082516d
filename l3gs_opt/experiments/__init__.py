"""The paper's experiments: plan, run and report.
"""
