"""The folder mapping (models/ -> l3gs_opt.models, ...) works in a plain wheel, not only editable."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def test_editable_install_maps_folders():
    import l3gs_opt.models
    import l3gs_opt.renderer
    import l3gs_opt.solvers

    assert Path(l3gs_opt.models.__file__).parent == REPO / "models"
    assert Path(l3gs_opt.solvers.__file__).parent == REPO / "solvers"
    assert Path(l3gs_opt.renderer.__file__).parent == REPO / "renderer"


@pytest.mark.slow
def test_plain_wheel_contains_and_imports_the_mapped_packages(tmp_path):
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(tmp_path / "dist"), str(REPO)], check=True, timeout=300)
    (wheel,) = (tmp_path / "dist").glob("l3gs_opt-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for member in ("l3gs_opt/models/__init__.py", "l3gs_opt/models/backends/highs.py",
                   "l3gs_opt/solvers/__init__.py", "l3gs_opt/renderer/__init__.py",
                   "l3gs_opt/data/traces/lumos-throughput-mid-11.txt", "l3gs_opt/data/traces/PROVENANCE.md"):
        assert member in names, member
    assert not any(n.startswith(("models/", "solvers/", "renderer/", "tests/")) for n in names)
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target), str(wheel)],
                   check=True, timeout=300)
    code = ("import l3gs_opt, l3gs_opt.models, l3gs_opt.solvers, l3gs_opt.renderer, pathlib;"
            "from l3gs_opt.pipeline.synth import synth_instance;"
            "i = synth_instance(objects=3, slots=5);"
            "print(pathlib.Path(l3gs_opt.models.__file__).resolve(), l3gs_opt.solve(i).status)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=120,
                          env={"PYTHONPATH": str(target), "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr
    path, status = proc.stdout.split()
    assert Path(path).is_relative_to(target.resolve()) and status == "optimal"


def test_public_api_names_all_resolve_and_solving_does_not_import_torch():
    code = ("import sys, l3gs_opt\n"
            "assert 'torch' not in sys.modules, 'import l3gs_opt pulled in torch'\n"
            "missing = [n for n in l3gs_opt.__all__ if not hasattr(l3gs_opt, n)]\n"
            "assert not missing, missing\n"
            "assert 'UtilityScene' in dir(l3gs_opt)\n"
            "try:\n    l3gs_opt.no_such_name\nexcept AttributeError as e:\n    assert 'no_such_name' in str(e)\n"
            "else:\n    raise SystemExit('no AttributeError')\n")
    subprocess.run([sys.executable, "-c", code], check=True)
