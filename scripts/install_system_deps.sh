#!/usr/bin/env bash
# Install the Debian packages Mimica needs that pip cannot provide:
#   - the xcb libraries Qt's "xcb" platform plugin loads (the real window),
#   - Mesa/EGL/GL for VTK rendering, fontconfig for Qt text,
#   - espeak-ng for lip-sync from text (phonemes with timings, speech audio),
#   - Xvfb + xauth so the window and GUI tests run on a machine without a screen.
# Usage: scripts/install_system_deps.sh          (installs what is missing)
# Set MIMICA_NO_APT=1 to only report what is missing.
set -euo pipefail

packages=(
  xvfb xauth
  libxcb-icccm4 libxcb-image0 libxcb-keysyms1 libxcb-randr0 libxcb-render-util0
  libxcb-shape0 libxcb-xinerama0 libxcb-xkb1 libxkbcommon-x11-0 libxcb-cursor0
  libegl1 libgl1 libfontconfig1 libdbus-1-3
  espeak-ng
)

missing=()
for pkg in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$pkg")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi

if [ "${MIMICA_NO_APT:-0}" = "1" ] || ! command -v apt-get >/dev/null 2>&1; then
  echo "Mimica needs these system packages, which are missing: ${missing[*]}" >&2
  echo "Install them with your package manager (Debian/Ubuntu: sudo apt-get install ${missing[*]})." >&2
  exit 1
fi

sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then sudo_cmd=(sudo); else
    echo "Missing system packages (${missing[*]}) and no root/sudo to install them." >&2
    exit 1
  fi
fi

echo "Installing system packages: ${missing[*]}"
"${sudo_cmd[@]}" apt-get update -qq
"${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
