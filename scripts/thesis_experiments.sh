#!/usr/bin/env bash
# Thesis chapter 4 at the thesis's scale, experiment by experiment, into one report folder that
# every call adds to (finished runs are kept and shared between experiments; a killed call resumes
# where it stopped). Then the small tables are copied to results/ (committed).
#
#   bash scripts/thesis_experiments.sh                       # every experiment, each file's seeds
#   SEEDS=2 bash scripts/thesis_experiments.sh methods tau   # some, with 2 seeds per setting
#
# The whole programme is about 8 hours on a 2-core CPU (docs/reproduction.md).
set -euo pipefail
OUT=${OUT:-runs/reproduce-thesis}
EXPERIMENTS=${*:-gamma rho buffer_iddpg buffer_seddpg buffer_snddpg buffer_flddpg fed_period_steps fed_period_episodes tau methods pw_beta rw_beta improvements}
SEED_FLAG=${SEEDS:+--seeds $SEEDS}
for e in $EXPERIMENTS; do
  # an aborted run (e.g. exit 134, a collective that missed XLA's 40 s timeout) resumes from its
  # last checkpoint: up to three tries per experiment
  for try in 1 2 3; do
    fedjax-nav reproduce --scale thesis --only "$e" $SEED_FLAG --out "$OUT" --quiet && break
    [ "$try" = 3 ] && exit 1
  done
done
# one report over everything done so far (trains nothing new)
fedjax-nav reproduce --scale thesis --only "$(echo $EXPERIMENTS | tr ' ' ',')" $SEED_FLAG --out "$OUT" --quiet
python scripts/collect_reproduction.py "$OUT" results
