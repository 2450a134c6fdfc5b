#!/usr/bin/env bash
# make check-systemd: deploy/jsar-service.service under a real systemd. Builds (if missing) the service
# image for this machine's architecture, then an image with systemd as PID 1 and the unit installed as
# documented (deploy/systemd-check.Containerfile), and runs tests/test_deploy_systemd.py against it.
# Needs root (privileged container). PYTHON: the interpreter with the project's test dependencies.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
# shellcheck source=deploy/lib.sh
. "$repo/deploy/lib.sh"
image="${JSAR_IMAGE:-localhost/jsar-service}"
arch="$(dpkg --print-architecture 2>/dev/null || uname -m)"
python="${PYTHON:-$repo/.venv/bin/python}"

ensure_packages podman=podman runc=runc
if ! podman image exists "$image:$arch"; then
    JSAR_IMAGE_ARCHES="$arch" "$repo/deploy/build-image.sh"
fi
# shellcheck disable=SC2207
limits=($(podman_limits))
echo "== $image-systemd:$arch (systemd as PID 1, the unit installed and enabled)"
nice -n 15 podman build --network host "${limits[@]}" --build-arg IMAGE="$image:$arch" \
    -t "$image-systemd:$arch" -f "$repo/deploy/systemd-check.Containerfile" "$repo"
if command -v systemd-analyze >/dev/null; then
    echo "== systemd-analyze security --offline (the unit file as committed)"
    systemd-analyze security --offline=true --no-pager "$repo/deploy/jsar-service.service" | tail -n 1
fi
cd "$repo"
JSAR_CHECK_SYSTEMD=1 JSAR_IMAGE="$image" "$python" -m pytest -q -rs -s tests/test_deploy_systemd.py
