#!/usr/bin/env bash
# Installs a built wheel into a fresh venv whose PATH has no Rust toolchain and runs it
# (scripts/wheel_smoke.py). Usage: scripts/check_wheel.sh WHEEL [DEPS_PYTHON]
#
# pip installs the wheel alone, with --no-index --no-deps --only-binary: nothing is
# downloaded and nothing is built, so a wheel that needed compiling would fail here. The
# runtime dependencies (torch, ...) are taken from DEPS_PYTHON's environment (default
# .venv) by a path entry, so the check costs no download; that environment's own
# plantdreamer is not picked up (its editable hook is a .pth file, not read from there).
set -euo pipefail
wheel=$(realpath "$1")
deps_python=${2:-.venv/bin/python}
root=$(cd "$(dirname "$0")/.." && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

"$deps_python" -m venv "$work/venv"
venv_python="$work/venv/bin/python"
clean_env=(env -i "PATH=$work/venv/bin" "HOME=$work" "LANG=C.UTF-8")
"${clean_env[@]}" "$venv_python" -m pip install --quiet --no-index --no-deps \
    --only-binary=:all: "$wheel"
site=$("$venv_python" -c 'import sysconfig; print(sysconfig.get_paths()["platlib"])')
"$deps_python" -c 'import sysconfig; p = sysconfig.get_paths(); print(p["purelib"]); print(p["platlib"])' \
    | sort -u > "$site/plantdreamer_check_deps.pth"
cd "$work"
"${clean_env[@]}" "$venv_python" "$root/scripts/wheel_smoke.py"
