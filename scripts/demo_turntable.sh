#!/usr/bin/env bash
# Regenerates docs/images/demo_bean_turntable.gif (the README's turntable): the L-System bean
# with --guidance none. (`make demo`'s picture is its own demo.png: docs/images/demo_known_answer.png.)
set -euo pipefail
cd "$(dirname "$0")/.."
make build
.venv/bin/plantdreamer generate --species bean --guidance none --out out/turntable --overwrite
.venv/bin/plantdreamer render out/turntable/plant.ply --out out/turntable/readme --eval-views 36 --resolution 256
cp out/turntable/readme/turntable.gif docs/images/demo_bean_turntable.gif
