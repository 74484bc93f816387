#!/usr/bin/env bash
# The 4-method comparison at thesis scale (125 episodes x 1024 steps, 5 robots), SEEDS seeds each,
# all seeds of a method in one program. Writes runs/thesis/<method>/ and results/thesis_methods.csv.
set -euo pipefail
SEEDS=${SEEDS:-4}
OUT=${OUT:-runs/thesis}
for m in ${METHODS:-flddpg iddpg snddpg seddpg}; do
  fedjax-nav train --config configs/thesis/$m.yaml --seeds "$SEEDS" --out "$OUT/$m" --quiet
done
python scripts/collect_summaries.py "$OUT" results/thesis_methods.csv
