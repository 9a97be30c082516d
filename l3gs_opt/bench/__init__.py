"""Benchmark suites, the run with its records, and the report.
"""
