#!/usr/bin/env bash
# The GPU checks of `jax_realism` as one prepared command, for a session lent a device machine (the
# workplace's `device` tool: one NVIDIA H200, Python 3.12 with JAX, no network, 15 minutes in all).
#
#   bash benchmarks/device_check.sh prepare   # here: the wheels the device lacks, the reference material
#   # then, with the device tool, one call (timeout_s 540, carry [".whl", ".device-shared"]):
#   bash benchmarks/device_check.sh run       # there: exactness, then speed; logs under $OUT
#
# `prepare` downloads cp312 wheels of the dependencies the device's Python lacks or holds in another
# version (google-crc32c, isal, protobuf: the versions of this checkout's venv where it has one) into
# .whl/, and copies the reference material the checks read (womd/, golden/: about 35 MB) into
# .device-shared/; both folders are git-ignored and travel only when `carry` names them.
#
# `run` installs the wheels into /tmp/site, then runs, each under its own time limit so that a slow step
# leaves the other its time (about 8 minutes in all, under the tool's 10 a call): the exact mode's
# exactness on every golden set (`jax_realism_exactness.py`, 180 s: the issue's goal is 3 minutes), and
# the training loop's batch sweep, both modes, with the closed-over row (`jax_realism_speed.py`, 300 s). Everything it prints is
# also in $OUT/device-check.log. Without $OUT (a trial run on this machine, CPU JAX) it writes to
# ./device-check-out; DEVICE_CHECK_SCENES (default 128,512,2048) and DEVICE_CHECK_PYTHON (default python3)
# make such a trial small and point it at a venv (which then uses its own packages, not the cp312 wheels).
set -uo pipefail
cd "$(dirname "$0")/.."
step=${1:-}

if [[ $step == prepare ]]; then
  set -e
  python=.venv/bin/python
  [[ -x $python ]] || python=python3
  version() { "$python" -m pip show "$1" 2>/dev/null | sed -n 's/^Version: //p'; }
  wheels=()
  for name in google-crc32c isal protobuf; do
    v=$(version "$name")
    wheels+=("$name${v:+==$v}")
  done
  rm -rf .whl && mkdir -p .whl
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
    --platform manylinux2014_x86_64 --platform manylinux1_x86_64 -d .whl "${wheels[@]}"
  shared=${WOSAC_SHARED:-../shared}
  rm -rf .device-shared && mkdir -p .device-shared
  cp -r "$shared/womd" "$shared/golden" .device-shared/
  ls .whl && du -sh .whl .device-shared
  exit 0
fi

if [[ $step != run ]]; then
  echo "usage: bash benchmarks/device_check.sh prepare|run" >&2
  exit 2
fi

out=${OUT:-device-check-out}
mkdir -p "$out"
log=$out/device-check.log
python=${DEVICE_CHECK_PYTHON:-python3}
scenes=${DEVICE_CHECK_SCENES:-128,512,2048}
export PYTHONUNBUFFERED=1 WOSAC_SHARED=$PWD/.device-shared
# The wheels are cp312's: a trial on another interpreter uses its own packages.
if compgen -G ".whl/*.whl" >/dev/null && "$python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 12))'; then
  "$python" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || exit 1
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD
fi
{
  echo "== $(date -u +%FT%TZ) $(git rev-parse --short HEAD 2>/dev/null || echo '?'); $(nvidia-smi -L 2>/dev/null | head -1)"
  "$python" -c 'import jax; print("JAX", jax.__version__, jax.devices())'
  echo "== exactness, exact mode, device search (limit 180 s)"
  SECONDS=0
  timeout 180 "$python" benchmarks/jax_realism_exactness.py exact device
  echo "(rc $?, ${SECONDS} s)"
  echo "== training loop, device search (limit 300 s)"
  SECONDS=0
  timeout 300 "$python" benchmarks/jax_realism_speed.py --womd --search device --scenes "$scenes" --repeat 5 \
    --closed-over "${scenes%%,*}"
  echo "(rc $?, ${SECONDS} s)"
} 2>&1 | tee "$log"
