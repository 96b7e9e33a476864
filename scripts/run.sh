#!/usr/bin/env bash
# Install everything Mimica needs (system libraries, virtual environment,
# Python packages) and start the app on the built-in default face.
# Extra arguments go to `mimica` (e.g. a face file to open).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/bootstrap.sh" ""
cd "$ROOT"
if [ "${MIMICA_JUST_INSTALLED:-0}" = 1 ]; then
  # The default face's FAP table and viewport draft go to the cache now, so the first start is quick.
  echo "Preparing the default face for animation (once, about ten seconds)"
  "$VENV/bin/mimica" prepare || echo "(not prepared: the window will build it at start-up)"
fi
# Byte-compile Mimica's own modules (quick when up to date): Python reads .pyc files even where
# PYTHONDONTWRITEBYTECODE is set (as on some machines and CI images), and compiling every module
# from source at each start costs 1-2 s on a 2-core machine.
"$VENV/bin/python" -m compileall -q app core resources >/dev/null || true
if [ -z "${DISPLAY:-}" ] && [ -z "${WAYLAND_DISPLAY:-}" ]; then
  echo "No display found: starting Mimica on a virtual X screen (Xvfb)."
  exec xvfb-run -a -s "-screen 0 1600x1000x24" "$VENV/bin/mimica" "$@"
fi
exec "$VENV/bin/mimica" "$@"
