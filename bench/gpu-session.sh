#!/bin/bash
# What a session lent an NVIDIA GPU runs (15 minutes of device time in all: prepare here first).
#
#   here, from the project root:  bash bench/gpu-session.sh kit
#     The offline kit (../shared/gpu-kit/make-kit.sh → .gpukit), plus the wheels of what glsim
#     and its GL tests import beyond the kit's list and what a device is taken to have ($DEVICE
#     below), at the versions .venv tests with. Then, where a Python 3.12 is here ($PY312,
#     default python3.12), the kit is installed as run.sh installs it into a Python 3.12 with only
#     $DEVICE, and the GL tier is collected with it: an import the kit lacks fails here, not on
#     the device's clock.
#
#   on the device (carry .gpukit), two calls in a row (a warm machine is given back when idle):
#     bash .gpukit/run.sh "$OUT" info tests quick      → $OUT/r.tgz
#     bash bench/gpu-session.sh run "$OUT" [probe] [check] [throughput]   → $OUT/gpu/
#     The second runs bench/gpu_probes.py (seconds: how the driver keeps local double arrays and
#     reads double literals; the same per-pixel work as a fragment and as a compute pass), `glsim
#     check` and the full throughput benchmark (all by default;
#     name some to split them over calls, each then shorter than a call's limit) with the kit installed the
#     same way; commit its results beside the llvmpipe ones: bench/results/check-<gpu>.json (add
#     it to the sources of README's "check-drivers" region, then `python -m tools.docs`: a column of that
#     table) and bench/results/throughput-<gpu>.{json,md}. QUICK=1: the benchmark's --quick (a dry run on
#     llvmpipe, with the kit's Python 3.12 first on PATH).
set -uo pipefail
# Beyond the kit: what glsim and the GL tests import that a bare Python 3.12 lacks, but matplotlib
# (the calibration tests' figures), taken to be on the device: with its dependencies it would take
# the kit past the 64 MiB a device call carries, and the H200 run of 2026-11-26
# (../shared/gpu-kit/nvidia-h200-*.txt) lists no calibration test among its failures.
EXTRA="rich markdown-it-py mdurl pygments hypothesis sortedcontainers imageio pillow tifffile certifi glfw"
DEVICE="numpy scipy opencv-python-headless pytest pytest-xdist pytest-timeout matplotlib"
PLAT="--platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform manylinux_2_34_x86_64 --platform any"
K=$PWD/.gpukit
PY312=${PY312:-python3.12}

install_kit() {  # $1: target folder; as .gpukit/run.sh installs it
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$1" "$K"/whl/*.whl 2>&1 | grep -v WARNING | tail -3 || true
  export PYTHONPATH=$1:$K/site PYTHONUNBUFFERED=1 PATH=$1/bin:$PATH
}

case ${1:-} in
kit)
  set -e
  test -x .venv/bin/python || { echo "run 'make venv' first: the extra wheels take .venv's versions" >&2; exit 2; }
  bash ../shared/gpu-kit/make-kit.sh
  pins=$(.venv/bin/python -c "import sys; from importlib.metadata import version
print(' '.join(f'{n}=={version(n)}' for n in sys.argv[1:]))" $EXTRA)
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp $PLAT -d "$K/whl" $pins 2>&1 | grep -v WARNING || true
  tree=$(git ls-files -z | du -cb --files0-from=- | tail -1 | cut -f1)
  mib=$(( ($(du -sb "$K" | cut -f1) + tree) / 1048576 ))
  echo "kit and working tree: $mib MiB"
  test "$mib" -lt 64 || { echo "over the 64 MiB a device call carries" >&2; exit 1; }
  if "$PY312" -c pass 2> /dev/null; then
    B=$PWD/build/gpukit-check; rm -rf "$B"; "$PY312" -m venv "$B/venv"
    "$B/venv/bin/python" -m pip install -q $DEVICE 2>&1 | grep -v WARNING || true
    export PATH=$B/venv/bin:$PATH
    install_kit "$B/site"
    cd "$K/src"
    python3 -m pytest -q --collect-only -m "gl and not slow" -p no:cacheprovider > "$B/collect.log" 2>&1 \
      || { grep -E "Error|error" "$B/collect.log" | sort | uniq -c | head -20; echo "the kit is incomplete: $B/collect.log" >&2; exit 1; }
    tail -1 "$B/collect.log"
  else
    echo "no Python 3.12 here (PY312=$PY312): the kit's completeness was not checked"
  fi
  ;;
run)
  O=${2:?output folder}; G=$O/gpu; mkdir -p "$G"
  if ! ldconfig -p | grep -q 'libEGL.so.1 '; then   # a fresh machine: glvnd's EGL, as run.sh does
    for f in "$K"/deb/*.deb; do dpkg -x "$f" /; done; ldconfig
  fi
  install_kit "$(mktemp -d)"
  if ! timeout 60 glsim info > "$G/info.txt" 2>&1; then
    export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
    timeout 60 glsim info > "$G/info.txt" 2>&1
  fi
  gpu=$(nvidia-smi --query-gpu=name --format=csv,noheader 2>/dev/null | head -1 | tr 'A-Z ' 'a-z-' | tr -cd 'a-z0-9-')
  gpu=${gpu:-unknown-gpu}
  steps=" ${*:3} "; [ "$steps" = "  " ] && steps=" probe check throughput "
  [[ $steps == *" probe "* ]] && { echo "== probe"; timeout 90 python3 bench/gpu_probes.py "$G/probes-$gpu.json" > "$G/probe.log" 2>&1; echo "rc=$?"; }
  [[ $steps == *" check "* ]] && { echo "== check ($gpu)"; timeout 150 glsim check --json "$G/check-$gpu.json" > "$G/check.log" 2>&1; echo "rc=$?"; tail -3 "$G/check.log"; }
  [[ $steps == *" throughput "* ]] && { echo "== throughput"; timeout 480 glsim bench throughput ${QUICK:+--quick} --out "$G/throughput-$gpu" > "$G/throughput.log" 2>&1; echo "rc=$?"; tail -3 "$G/throughput.log"; }
  true ;;
*)
  sed -n '2,16p' "$0"; exit 2 ;;
esac
