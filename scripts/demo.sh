#!/usr/bin/env bash
# The main job: set up, then run the end-to-end demo on the embedded synthetic world.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/bimcap demo -o "${1:-demo_out}"
