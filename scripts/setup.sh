#!/usr/bin/env bash
# Create .venv/ at the repository root when missing and install the project into it
# (editable, with test extras), pinning torch to the CPU build through constraints.txt.
# Re-running is cheap: pip is skipped while pyproject.toml and constraints.txt are unchanged.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
py=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    "$py" -m venv .venv
fi
stamp=.venv/.l3gs-opt-installed
want=$(cat pyproject.toml constraints.txt | sha256sum | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ] || [ ! -x .venv/bin/l3gs-opt ]; then
    echo "setting up .venv (pip install -e .[test], torch pinned to the CPU build) ..." >&2
    log=.venv/pip-install.log
    if ! { .venv/bin/python -m pip install --upgrade pip \
           && .venv/bin/python -m pip install -c constraints.txt -e ".[test]"; } > "$log" 2>&1; then
        cat "$log" >&2
        echo "set-up failed; the pip log is $log" >&2
        exit 1
    fi
    echo "$want" > "$stamp"
fi
# exact's numba kernels, compiled once per machine (~9 s the first time, ~0.3 s to check after):
# a solve under a time limit never waits for a compile, so without this a fresh machine's first
# timed solves would run without them.
.venv/bin/python -c "import l3gs_opt; l3gs_opt.warm_up()"
