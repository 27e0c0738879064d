# brl in a container: CPU-only, headless, non-root (uid 1000), read-only root filesystem friendly.
#
#   docker build --build-arg GIT_COMMIT="$(git rev-parse HEAD)" -t brl .
#   docker run --rm -v brlout:/work/out brl preview --out /work/out/preview          # a named volume
#   mkdir -p out && docker run --rm --user "$(id -u):$(id -g)" -v "$PWD/out:/work/out" brl preview --out /work/out/preview
#
# Dependencies are installed in their own layer from docker/requirements.lock (pinned; torch is the CPU build)
# before the source is copied, so a change to brlcli/ rebuilds in seconds. To stay small the image drops what brl
# never loads (headers, test suites, example assets), strips debug symbols from its largest libraries, keeps no apt
# caches (the operating system is flattened into one layer, so that what the base image brought is gone too) and
# ships bytecode only for the dependency modules brl loads (docker/precompile.txt), written next to their sources
# so that any uid uses it read-only. Ray is included (ray[default], with wget for KubeRay's health probes): the
# same image is the head and the worker image of a KubeRay cluster. brl's version (importlib.metadata, in every
# output's provenance and `brl --version`) comes from pyproject.toml: the source runs from /opt/brl (PYTHONPATH),
# with a dist-info record of its name and version in the virtual environment.
#
# Build arguments, for machines where Docker Hub, PyPI or download.pytorch.org are not directly reachable:
#   BASE_IMAGE        a Debian-based image with python3 (3.11) and python3-venv   (default python:3.11-slim)
#   PIP_INDEX_URL     the package index (a mirror)                                  (default PyPI)
#   TORCH_INDEX       where the CPU build of torch comes from; empty: only docker/wheels/ (default PyTorch's CPU index)
#   EXTRA_CA_CERTS    PEM text of extra CA certificates (a TLS-inspecting proxy): --build-arg EXTRA_CA_CERTS="$(cat ca.pem)"
#   GIT_COMMIT        recorded as the git commit in every output's provenance    (default unknown)
# Wheels placed in docker/wheels/ (e.g. a local torch CPU wheel) are preferred to the indexes.

ARG BASE_IMAGE=python:3.11-slim

# The operating system of the final image: the base with wget, less apt's caches and package lists, message
# translations and manual pages, with the standard library's bytecode (a no-op where the base has it, as Debian's
# python3 does); flattened below into a single layer, since a file deleted in a later layer still counts in the size.
FROM ${BASE_IMAGE} AS os
RUN (command -v wget >/dev/null || (apt-get update && apt-get install -y --no-install-recommends wget)) \
    && apt-get clean \
    && rm -rf /var/lib/apt/lists/* /var/cache/apt/*.bin /var/cache/apt/archives/*.deb /var/cache/apt/archives/partial/* \
        /var/log/apt/* /var/log/dpkg.log /usr/share/man/* /usr/share/info/* \
    && find /usr/share/locale -mindepth 1 -maxdepth 1 -type d -exec rm -rf {} + \
    && python3 -m compileall -q "$(python3 -c 'import sysconfig; print(sysconfig.get_paths()["stdlib"])')" \
    && mkdir -p /work/out && chown 1000:1000 /work /work/out && chmod 1777 /work /work/out

FROM ${BASE_IMAGE} AS deps
ARG PIP_INDEX_URL=https://pypi.org/simple
ARG TORCH_INDEX=https://download.pytorch.org/whl/cpu
ARG EXTRA_CA_CERTS=
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_ROOT_USER_ACTION=ignore PIP_NO_COMPILE=1
RUN if [ -n "$EXTRA_CA_CERTS" ]; then \
        printf '%s\n' "$EXTRA_CA_CERTS" > /usr/local/share/ca-certificates/extra.crt && update-ca-certificates; \
    fi \
    && apt-get update && apt-get install -y --no-install-recommends binutils \
    && apt-get clean && rm -rf /var/lib/apt/lists/* /var/cache/apt/*.bin /var/cache/apt/archives/*.deb
RUN python3 -m venv /opt/venv
COPY docker/requirements.lock /tmp/requirements.lock
COPY docker/wheels/ /tmp/wheels/
RUN /opt/venv/bin/pip install --index-url "$PIP_INDEX_URL" ${TORCH_INDEX:+--extra-index-url "$TORCH_INDEX"} \
        --find-links /tmp/wheels --cert /etc/ssl/certs/ca-certificates.crt -r /tmp/requirements.lock \
    # what brl never loads: C++ headers, test suites and test binaries, pybullet's example assets, Ray's Java jars
    && cd /opt/venv/lib/python3*/site-packages \
    && rm -rf torch/include torch/test torch/testing/_internal/opinfo torch/lib/libtorchbind_test.so \
        torch/lib/libaoti_custom_ops.so torch/lib/libbackend_with_compiler.so \
        pybullet_data pybullet_envs pybullet_robots pybullet_utils/examples eglRenderer*.so \
        ray/jars ray/rllib ray/tests scipy/*/tests numpy/*/tests pandas/tests \
    && find torch/bin -type f ! -name torch_shm_manager -delete \
    # debug symbols of the three largest libraries (pybullet's shrinks from 140 MB to 8 MB); not of libraries that
    # auditwheel patched (numpy.libs and the like), which stripping breaks
    && strip --strip-unneeded pybullet.cpython-*.so llvmlite/binding/libllvmlite.so torch/lib/libtorch_cpu.so \
    && find . -name __pycache__ -type d -prune -exec rm -rf {} +
# bytecode of the dependency modules brl loads (~60 MB; all of it would be ~250 MB), written where any uid reads it
COPY docker/precompile.py docker/precompile.txt /tmp/
RUN /opt/venv/bin/python3 /tmp/precompile.py /tmp/precompile.txt

FROM scratch
COPY --from=os / /
ENV PYTHONUNBUFFERED=1 \
    PYTHONPATH=/opt/brl \
    PATH=/opt/venv/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    LANG=C.UTF-8 \
    OMP_NUM_THREADS=1 \
    HOME=/tmp \
    MPLCONFIGDIR=/tmp/matplotlib \
    NUMBA_CACHE_DIR=/tmp/numba
COPY --from=deps /opt/venv /opt/venv
COPY towns /opt/brl/towns
COPY models /opt/brl/models
# brl's name and version for importlib.metadata (what `pip install` of the source would record), from pyproject.toml
COPY pyproject.toml /tmp/pyproject.toml
RUN python3 -c "import pathlib, sysconfig, tomllib; \
v = tomllib.loads(pathlib.Path('/tmp/pyproject.toml').read_text())['project']['version']; \
d = pathlib.Path(sysconfig.get_paths()['purelib'], f'brl-{v}.dist-info'); d.mkdir(); \
(d / 'METADATA').write_text(f'Metadata-Version: 2.1\\nName: brl\\nVersion: {v}\\n'); \
(d / 'INSTALLER').write_text('docker\\n')" \
    && rm /tmp/pyproject.toml \
    && printf '#!/bin/sh\nexec python3 -m brlcli "$@"\n' > /opt/venv/bin/brl && chmod 755 /opt/venv/bin/brl
COPY brlcli /opt/brl/brlcli
RUN python3 -m compileall -q /opt/brl/brlcli
# last, so that a new commit invalidates no layer above
ARG GIT_COMMIT=unknown
ENV BRL_GIT_COMMIT=${GIT_COMMIT}
USER 1000:1000
WORKDIR /work
ENTRYPOINT ["brl"]
CMD ["--help"]
