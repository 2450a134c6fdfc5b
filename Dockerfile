# syntax=docker/dockerfile:1
# The onboard tracking service as a container image, amd64 and arm64 (built and run: docs/deploy.md).
# With a registry, the default base (the official python image, published for linux/amd64 and
# linux/arm64) works unchanged:
#   podman build --arch arm64 -t jsar-service .        (or: docker buildx build --platform linux/arm64 ...)
# Without one, `make image` builds a local base from Debian's packages (bookworm + python3, via
# mmdebstrap and `podman import`) and passes it as BASE_IMAGE.
#   podman run --rm --network host --device /dev/video0 -v /etc/jsar:/etc/jsar:ro jsar-service
# Dependencies are exactly the pinned ones of pyproject.toml (no opencv-python next to the contrib wheel).
ARG BASE_IMAGE=docker.io/library/python:3.11-slim-bookworm

FROM ${BASE_IMAGE} AS build
# A C compiler for the tracker's compiled feature kernels (setuptools ext-modules), and Python's
# headers where the base lacks them (Debian's python3 keeps them in python3-dev; the python image has them).
RUN set -eu; \
    packages="gcc libc6-dev"; \
    include="$(python3 -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"; \
    [ -f "$include/Python.h" ] || packages="$packages python3-dev"; \
    apt-get update; \
    apt-get install -y --no-install-recommends $packages; \
    rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY pyproject.toml README.md requirements-no-deps.txt ./
COPY jsar ./jsar
COPY service ./service
COPY sim ./sim
COPY gcs ./gcs
# (the check runs from / so that it imports the installed package, not the source tree)
RUN python3 -m venv /opt/jsar/.venv \
    && /opt/jsar/.venv/bin/pip install --no-cache-dir --upgrade pip \
    && /opt/jsar/.venv/bin/pip install --no-cache-dir . \
    && /opt/jsar/.venv/bin/pip install --no-cache-dir --no-deps -r requirements-no-deps.txt \
    && cd / \
    && /opt/jsar/.venv/bin/python -c "import cv2; cv2.TrackerCSRT_create(); import jsar.features._native; import jsar.registry as r; print(r.available()); from jsar.learnt.mobilenet import FeatureNet; FeatureNet(8)"

FROM ${BASE_IMAGE}
# non-root user in the groups that own cameras (video) and serial links to the autopilot (dialout)
RUN useradd --system --uid 10001 --user-group --groups video,dialout --home-dir /opt/jsar --no-create-home jsar
COPY --from=build /opt/jsar/.venv /opt/jsar/.venv
COPY config.yaml /etc/jsar/config.yaml
ENV PATH=/opt/jsar/.venv/bin:$PATH \
    MAVLINK20=1 \
    OMP_NUM_THREADS=1 \
    OPENBLAS_NUM_THREADS=1 \
    MKL_NUM_THREADS=1 \
    PYTHONUNBUFFERED=1
USER jsar
WORKDIR /opt/jsar
# SIGTERM (podman / docker stop) stops the daemon cleanly within 2 s
STOPSIGNAL SIGTERM
ENTRYPOINT ["jsar-service"]
CMD ["--config", "/etc/jsar/config.yaml"]
