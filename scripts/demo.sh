#!/usr/bin/env bash
# The README's first command: set up, then run the demo on the built-in default.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$root/scripts/setup.sh"
exec "$root/.venv/bin/l3gs-opt" demo "$@"
