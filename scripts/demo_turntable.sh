#!/usr/bin/env bash
# Regenerates docs/images/demo_bean_turntable.gif (the README's turntable) from `make demo`.
set -euo pipefail
cd "$(dirname "$0")/.."
make demo DEMO_OUT=out/demo
.venv/bin/plantdreamer render out/demo/plant.ply --out out/demo/readme --eval-views 36 --resolution 256
cp out/demo/readme/turntable.gif docs/images/demo_bean_turntable.gif
