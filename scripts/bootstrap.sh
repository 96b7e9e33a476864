# Sourced by run.sh and test.sh: make sure system packages, the virtual
# environment and the Python dependencies are in place. Idempotent and quick
# when nothing changed (a stamp records the installed pyproject.toml).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${MIMICA_VENV:-$ROOT/.venv}"
EXTRAS="${1:-}"

"$ROOT/scripts/install_system_deps.sh"

PYTHON="${PYTHON:-python3}"
if ! "$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
  echo "Mimica needs Python 3.11 or newer; '$PYTHON' is $("$PYTHON" --version 2>&1). Set PYTHON=/path/to/python3.11." >&2
  exit 1
fi
if [ ! -x "$VENV/bin/python" ]; then
  echo "Creating the virtual environment in $VENV"
  "$PYTHON" -m venv "$VENV"
fi

stamp="$VENV/.mimica-installed${EXTRAS:+-$EXTRAS}"
want="$(sha256sum "$ROOT/pyproject.toml" | cut -d' ' -f1)"
# The test install includes the plain one: after test.sh, run.sh has nothing to install.
if [ -z "$EXTRAS" ] && [ -f "$VENV/.mimica-installed-test" ] && [ "$(cat "$VENV/.mimica-installed-test")" = "$want" ]; then
  stamp="$VENV/.mimica-installed-test"
fi
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "Installing Mimica and its Python dependencies (first run takes a minute)"
  "$VENV/bin/python" -m pip install --quiet --upgrade pip >/dev/null 2>&1 || true
  # The build backend warns about every editable install of a flat layout; the first screen stays clean.
  PYTHONWARNINGS=ignore "$VENV/bin/python" -m pip install --quiet -e "$ROOT${EXTRAS:+[$EXTRAS]}" 2>&1 | grep -v "^WARNING: Location" || true
  "$VENV/bin/python" -c "import app, core, resources" || { echo "Installation failed (see messages above)." >&2; exit 1; }
  echo "$want" > "$stamp"
  MIMICA_JUST_INSTALLED=1
fi
