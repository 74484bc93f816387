#!/usr/bin/env bash
# One point of the clutter_1e8 sweep (docs/clutter.md) trained and evaluated in one call on a GPU:
# the federated fleet (or METHOD), SEEDS seeds, stopped cleanly (SIGINT: the chunk finishes and is
# saved) after TRAIN_S seconds, then evaluated on the held-out suites; the run's tables go to OUT.
#   OUT=/tmp/out TRAIN_S=330 bash scripts/clutter_gpu.sh            # the GPU run
#   OUT=/tmp/out TRAIN_S=120 EXTRA="--set env.envs_per_robot=4 --set ppo.minibatches=4 \
#     --set run.episodes=2 --set env.episode_length=64 --set ppo.rollout=32" bash scripts/clutter_gpu.sh   # a CPU smoke
set -uo pipefail
OUT=${OUT:?set OUT}; TRAIN_S=${TRAIN_S:-330}; SEEDS=${SEEDS:-2}; METHOD=${METHOD:-flddpg}; RUN=${RUN:-/tmp/clutter_run}
export PYTHONUNBUFFERED=1 MPLBACKEND=Agg
SETS=$(python3 - <<'PY'
from fedjax_nav.config.io import read_yaml
from fedjax_nav.configs import SWEEP_DIR
print(" ".join(f"--set {s}" for s in read_yaml(SWEEP_DIR / "clutter_1e8.yaml")["set"]))
PY
)
python3 -c "import jax; print('devices', jax.devices())" | tee "$OUT/devices.txt"
start=$(date +%s)
timeout -s INT "$TRAIN_S" python3 -m fedjax_nav.cli train --config learners/ppo-gru $SETS \
  --set method="$METHOD" --set run.seeds="$SEEDS" --set run.episodes="${EPISODES:-38}" ${EXTRA:-} --out "$RUN" --overwrite 2>&1 | tr '\r' '\n' | tee "$OUT/train.log" | tail -5
echo "train wall $(( $(date +%s) - start )) s" | tee -a "$OUT/train.log"
for suite in dense-heldout indoor-heldout heldout; do
  python3 -m fedjax_nav.cli evaluate "$RUN" --suite "$suite" --no-figures 2>&1 | tail -12 | tee -a "$OUT/eval.log"
done
tar czf "$OUT/run.tgz" --exclude='checkpoints' --exclude='*.ckpt' -C "$(dirname "$RUN")" "$(basename "$RUN")"
ls -la "$OUT"
