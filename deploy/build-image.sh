#!/usr/bin/env bash
# make image: build the Dockerfile with podman for amd64 and arm64 (arm64 under qemu-user emulation).
# Without BASE_IMAGE a local base is made from Debian's packages (bookworm + python3 via mmdebstrap,
# then `podman import`), because no registry is needed that way; with a registry,
# BASE_IMAGE=docker.io/library/python:3.11-slim-bookworm (the Dockerfile's default) works unchanged.
# Environment:
#   JSAR_IMAGE         image name (default localhost/jsar-service; tags :amd64, :arm64, :latest = this machine's)
#   JSAR_IMAGE_ARCHES  architectures to build (default "amd64 arm64")
#   JSAR_IMAGE_CACHE   where the base root file systems are made (default ~/.cache/jsar-image)
#   BASE_IMAGE         base image for both stages (default: the local Debian base)
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
# shellcheck source=deploy/lib.sh
. "$repo/deploy/lib.sh"
image="${JSAR_IMAGE:-localhost/jsar-service}"
arches="${JSAR_IMAGE_ARCHES:-amd64 arm64}"
cache="${JSAR_IMAGE_CACHE:-$HOME/.cache/jsar-image}"
base="${BASE_IMAGE:-}"
nice_="nice -n 15"
host_arch="$(dpkg --print-architecture 2>/dev/null || uname -m)"

ensure_packages podman=podman runc=runc
[ -z "$base" ] && ensure_packages mmdebstrap=mmdebstrap
case " $arches " in *" arm64 "*) ensure_binfmt_aarch64;; esac
# shellcheck disable=SC2207
limits=($(podman_limits))
trust=()
for file in $(trust_files); do trust+=(--volume "$file:$file:ro"); done

for arch in $arches; do
    from="$base"
    if [ -z "$from" ]; then
        from="localhost/jsar-base:bookworm-$arch"
        if ! podman image exists "$from"; then
            echo "== local base $from (mmdebstrap: Debian bookworm minbase + python3)"
            mkdir -p "$cache"
            $nice_ mmdebstrap --arch="$arch" --variant=minbase --include=python3,python3-venv,passwd,ca-certificates \
                bookworm "$cache/base-$arch.tar"
            podman import --arch "$arch" --change 'CMD ["/bin/bash"]' "$cache/base-$arch.tar" "$from"
            rm -f "$cache/base-$arch.tar"
        fi
    fi
    echo "== $image:$arch from $from"
    start=$(date +%s)
    $nice_ podman build --arch "$arch" --network host "${limits[@]}" "${trust[@]}" --build-arg BASE_IMAGE="$from" \
        -t "$image:$arch" -f "$repo/Dockerfile" "$repo"
    echo "built $image:$arch in $(( $(date +%s) - start )) s"
    podman run --rm --arch "$arch" "${limits[@]}" --entrypoint python3 "$image:$arch" -c \
        "import platform, jsar.features._native as n; print('runs on', platform.machine(), 'kernels', n.kernels.__file__.rsplit('/', 1)[1])"
    [ "$arch" = "$host_arch" ] && podman tag "$image:$arch" "$image:latest"
done
echo "== image sizes"
podman image ls --filter "reference=$image" --format '{{.Repository}}:{{.Tag}}  {{.Size}}  {{.Digest}}' 
