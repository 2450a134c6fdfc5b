# syntax=docker/dockerfile:1
# The onboard tracking service as a container, multi-arch (the python base image is published for
# linux/amd64, linux/arm64 and linux/arm/v7):
#   docker buildx build --platform linux/amd64,linux/arm64 -t jsar-service .
#   docker run --rm --network host --device /dev/video0 -v /etc/jsar:/etc/jsar:ro jsar-service
# Dependencies are exactly the pinned ones of pyproject.toml (no opencv-python next to the contrib wheel).
ARG PYTHON_IMAGE=python:3.11-slim-bookworm

FROM ${PYTHON_IMAGE} AS build
# a C compiler for the tracker's compiled feature kernels (setuptools ext-modules)
RUN apt-get update \
    && apt-get install -y --no-install-recommends gcc libc6-dev \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY pyproject.toml README.md ./
COPY jsar ./jsar
COPY service ./service
COPY sim ./sim
COPY gcs ./gcs
RUN python -m venv /opt/jsar/.venv \
    && /opt/jsar/.venv/bin/pip install --no-cache-dir --upgrade pip \
    && /opt/jsar/.venv/bin/pip install --no-cache-dir . \
    && /opt/jsar/.venv/bin/python -c "import cv2; cv2.TrackerCSRT_create(); import jsar.registry as r; print(r.available())"

FROM ${PYTHON_IMAGE}
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
# SIGTERM (docker stop) stops the daemon cleanly within 2 s
STOPSIGNAL SIGTERM
ENTRYPOINT ["jsar-service"]
CMD ["--config", "/etc/jsar/config.yaml"]
