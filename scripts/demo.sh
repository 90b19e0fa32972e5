#!/usr/bin/env bash
# The main job on the bundled sample: install EVP, describe the sequence, estimate its trajectory
# and evaluate it against the ground truth (results, plots and settings in runs/sample/).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/evp info data/sample/davis_slider_depth
.venv/bin/evp run data/sample/davis_slider_depth --out runs/sample
