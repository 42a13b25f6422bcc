#!/usr/bin/env bash
# The Go1 joystick transfer matrix on the device machine (one H200, 16 cores, no network),
# in one command of at most 10 minutes: docs/training.md, "Transfer matrix on Go1 (GPU,
# prepared, unrun)". From the repository root, with the wheels of .whl/ carried:
#
#   run(command="bash benchmarks/gpu_go1_transfer.sh", carry=[".whl"], timeout_s=600)
#
# Extra arguments go to `python -m jax_contact.benchmarks.gpu_go1_transfer` (e.g.
# `--timesteps 32768000`, `--seeds 0 1`). The machine's python3 (3.12, jax 0.11.2 with its
# CUDA plugin, flax, optax, orbax-checkpoint, h5py, matplotlib preinstalled) gets the
# packages it lacks from .whl/ (MuJoCo, MJX, Brax, Playground and the few they import
# beyond the image's: the list and how to download them are in docs/training.md), and
# jax_contact as pyproject.toml's package-dir lays it out, copied: no build backend needed.
# Brax 0.14.2's PPO on jax 0.11: train/_compat.py. Everything it writes is under $OUT.
set -u
REPO=$(pwd)
OUT=${OUT:-$REPO/out/gpu_go1_transfer}
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
STARTED=$(python3 -c 'import time; print(time.time())')
exec > >(tee -a "$OUT/gpu_go1_transfer.log") 2>&1

echo "[gpu_go1_transfer.sh] $(date -u +%FT%TZ) $(python3 --version) in $REPO"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true

SITE=${SITE:-/tmp/site}
if ls "$REPO"/.whl/*.whl >/dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target "$SITE" "$REPO"/.whl/*.whl || { echo "pip install of .whl/ failed"; exit 3; }
else
  echo "no .whl/*.whl: carry .whl (docs/training.md lists the wheels)"; exit 3
fi
PKG=/tmp/jc  # jax_contact with envs/, train/, benchmarks/ inside, as the wheel installs them
rm -rf "$PKG" && mkdir -p "$PKG"
cp -r "$REPO/jax_contact" "$PKG/"
for sub in envs train benchmarks; do cp -r "$REPO/$sub" "$PKG/jax_contact/$sub"; done
export PYTHONPATH="$PKG:$SITE${PYTHONPATH:+:$PYTHONPATH}"
export JAX_CONTACT_CACHE_DIR=""  # a fresh machine: writing the cache would only cost time
export JAX_CONTACT_PROGRESS=0
export TF_CPP_MIN_LOG_LEVEL=${TF_CPP_MIN_LOG_LEVEL:-3}
echo "[gpu_go1_transfer.sh] installed in $(( $(date +%s) - ${STARTED%.*} )) s"

# From /tmp: the repository's own jax_contact/ (without envs/, train/) must not shadow $PKG's.
cd /tmp
# Everything the run imports, from the image or .whl/: a missing one is one line, at once.
python3 - <<'PY' || exit 3
import importlib, sys
need = ("jax jaxlib flax optax orbax.checkpoint h5py matplotlib scipy numpy etils absl yaml"
        " mujoco mujoco.mjx brax mujoco_playground ml_collections jaxopt trimesh lxml tqdm"
        " jax_contact.train.ppo").split()
missing = []
for name in need:
    try:
        importlib.import_module(name)
    except Exception as err:  # ImportError, or a wheel built for another Python
        missing.append(f"{name} ({type(err).__name__}: {err})")
if missing:
    print("[gpu_go1_transfer.sh] cannot import: " + "; ".join(missing), flush=True)
    sys.exit(3)
import jax
print(f"[gpu_go1_transfer.sh] imports ok: jax {jax.__version__} on {jax.devices()}", flush=True)
PY
python3 -m jax_contact.benchmarks.gpu_go1_transfer run --out "$OUT" \
  --started-at "$STARTED" "$@"
rc=$?
echo "[gpu_go1_transfer.sh] exit $rc after $(( $(date +%s) - ${STARTED%.*} )) s"
exit $rc
