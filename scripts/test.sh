#!/usr/bin/env bash
# The README's second command: set up, then run the test suite (extra arguments go to pytest).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$root/scripts/setup.sh"
# The replay page's browser test drives a headless chromium; install it when this machine allows
# (root with apt-get), bounded in time. Without it that one test skips and says why.
if ! command -v chromedriver >/dev/null 2>&1 && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 \
        && [ -z "${L3GS_NO_APT:-}" ]; then
    echo "installing chromium for the browser test (set L3GS_NO_APT=1 to skip) ..." >&2
    { timeout 300 apt-get update -qq && DEBIAN_FRONTEND=noninteractive timeout 600 \
        apt-get install -y -qq chromium chromium-driver; } >/dev/null 2>&1 \
        || echo "chromium could not be installed: the browser test will skip" >&2
fi
cd "$root"
exec .venv/bin/python -m pytest "$@"
