#!/usr/bin/env bash
# Set up headplod on a fresh Debian/Ubuntu machine, idempotently:
# system packages (libusb for camera identity), a venv in .venv, the package
# with its test extras. Re-running does nothing that is already done.
set -euo pipefail
cd "$(dirname "$0")"

APT_PACKAGES="libusb-1.0-0 libegl1 libgl1-mesa-dri"   # camera identity; offscreen OpenGL (EGL, Mesa llvmpipe)
# The preview window (pyglet through moderngl-window: GLX and X11 libraries), and its test under a virtual X
# server (Xvfb) that sends it real key events (xdotool); docs/plod.md's xvfb-run comes with xvfb.
APT_PACKAGES="$APT_PACKAGES libgl1 libglx-mesa0 libx11-6 libxext6 xvfb xdotool"
missing=""
for pkg in $APT_PACKAGES; do
    dpkg -s "$pkg" >/dev/null 2>&1 || missing="$missing $pkg"
done
if [ -n "$missing" ] && ! command -v apt-get >/dev/null 2>&1; then
    echo "setup: no apt-get here; install$missing with the system's package manager (camera identity, the" \
         "preview window and its test need them)" >&2
elif [ -n "$missing" ]; then
    echo "setup: installing system packages:$missing" >&2
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    if $SUDO apt-get install -y --no-install-recommends $missing >/dev/null 2>&1 \
        || { $SUDO apt-get update -qq && $SUDO apt-get install -y --no-install-recommends $missing; }; then
        :
    else
        echo "setup: could not install$missing with apt-get; camera identity (headplod cameras) needs libusb-1.0," \
             "the preview window libGL and X11, its test xvfb and xdotool" >&2
    fi
fi

PYTHON="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv" >&2
    "$PYTHON" -m venv .venv
fi
stamp=.venv/.headplod-installed
want="$({ cat pyproject.toml; ls -1 */__init__.py; } 2>/dev/null | sha256sum | cut -d" " -f1)"  # packages are mapped at install time
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    echo "setup: installing headplod and its dependencies into .venv" >&2
    .venv/bin/python -m pip install --quiet --upgrade pip >/dev/null 2>&1 || true
    .venv/bin/python -m pip install --quiet -e '.[test]'
    echo "$want" > "$stamp"
fi
