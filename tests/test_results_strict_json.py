"""Every JSON and JSONL file under ``benchmarks/results`` is strict JSON: no ``NaN`` or ``Infinity``
(which ``json`` writes by default and jq, JavaScript and the package's own record reader refuse).
The benchmark scripts write through :func:`l3gs_opt.jsonout.dumps`, where a non-finite number is null."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
FILES = sorted(p for p in RESULTS.rglob("*") if p.suffix in (".json", ".jsonl"))


def _refuse(token: str):
    raise ValueError(f"non-finite number {token}")


def test_there_are_result_files():
    assert len(FILES) > 20


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(RESULTS)))
def test_result_file_is_strict_json(path):
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".json":
        json.loads(text, parse_constant=_refuse)
        return
    for n, line in enumerate(text.splitlines(), 1):
        if line.strip():
            try:
                json.loads(line, parse_constant=_refuse)
            except ValueError as exc:
                raise AssertionError(f"{path.name} line {n}: {exc}") from None
