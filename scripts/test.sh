#!/usr/bin/env bash
# Install Mimica with its test dependencies (and Xvfb), then run the whole
# test suite on a virtual X screen. Extra arguments go to pytest.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/bootstrap.sh" "test"
cd "$ROOT"
exec xvfb-run -a -s "-screen 0 1600x1000x24" "$VENV/bin/python" -m pytest "$@"
