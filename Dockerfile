# brl in a container: CPU-only, headless, non-root. Build: docker build -t brl .
# Run:   docker run --rm -v "$PWD/out:/work/out" brl preview --out /work/out/preview
# Ray is included (the ray extra, with ray[default]'s dashboard agent and wget for KubeRay's health probes), so the
# same image serves as the head and worker image of a KubeRay cluster (README: Running on a Ray cluster).
FROM python:3.11-slim

ARG TORCH_VERSION=2.13.0
ARG TORCH_INDEX=https://download.pytorch.org/whl/cpu

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    OMP_NUM_THREADS=1

RUN apt-get update \
    && apt-get install -y --no-install-recommends git libglib2.0-0 libgomp1 wget \
    && rm -rf /var/lib/apt/lists/*

# CPU-only torch first, so that the project's `torch` requirement does not pull a CUDA build
RUN pip install --index-url "${TORCH_INDEX}" "torch==${TORCH_VERSION}"

WORKDIR /opt/brl
COPY pyproject.toml README.md ./
COPY brlcli ./brlcli
COPY towns ./towns
COPY models ./models
RUN pip install '.[ray]' 'ray[default]>=2.60,<3'

RUN useradd --create-home --uid 1000 brl && mkdir -p /work && chown brl:brl /work
USER brl
WORKDIR /work
ENTRYPOINT ["brl"]
CMD ["--help"]
