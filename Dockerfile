# Tessera: one image for both roles, the coordinator (`python -m server`) and the render node
# (`python -m node`). Renders on Mesa llvmpipe through EGL on any host; with docker-compose.gpu.yml
# the NVIDIA container toolkit adds the NVIDIA EGL driver and the same image renders on the GPU.
#
# Offline hosts (no image registry): run scripts/docker-base first; it builds debian:bookworm-slim
# from Debian packages and fills docker/wheels/, which the builder installs from with --no-index.
# With docker/wheels/ empty the dependencies come from PyPI as usual.

FROM debian:bookworm-slim AS python
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3 python3-venv \
    && rm -rf /var/lib/apt/lists/*
# The legacy builder keeps the last image of each stage but the final one as an untagged image (the
# builder's is the cache of the dependency layers): the label, which both stages below inherit,
# finds them; `docker image prune --filter label=tessera.stage=builder` removes them.
LABEL tessera.stage=builder

# pyproject.toml's runtime dependencies alone: an edit elsewhere in the file (scripts, test extras)
# makes the same requirements.txt, and the builder's install below stays cached.
FROM python AS requirements
COPY pyproject.toml /build/
RUN python3 -c 'import tomllib; print("\n".join(tomllib.load(open("/build/pyproject.toml", "rb"))["project"]["dependencies"]))' \
        > /build/requirements.txt

FROM python AS builder
RUN python3 -m venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_NO_CACHE_DIR=1
# Dependencies before source, so editing the source reuses this layer.
COPY docker/wheels/ /wheels/
COPY --from=requirements /build/requirements.txt /build/
RUN if ls /wheels/*.whl >/dev/null 2>&1; then offline="--no-index --find-links /wheels"; else offline=""; fi \
    && pip install $offline -r /build/requirements.txt \
    && pip uninstall --yes pip \
    && find /opt/venv \( -name __pycache__ -o -name tests \) -type d -prune -exec rm -rf {} +

FROM debian:bookworm-slim
# python3 and the EGL/GL runtime: glvnd (libegl1, libgl1) with Mesa's EGL vendor and llvmpipe (CPU).
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3 libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri libgbm1 \
    && rm -rf /var/lib/apt/lists/*
# glvnd's EGL vendor file for the NVIDIA driver; ignored where libEGL_nvidia.so.0 is absent (CPU hosts).
RUN mkdir -p /usr/share/glvnd/egl_vendor.d \
    && printf '{"file_format_version": "1.0.0", "ICD": {"library_path": "libEGL_nvidia.so.0"}}\n' \
        > /usr/share/glvnd/egl_vendor.d/10_nvidia.json
# /data (the coordinator's --data-dir) and /var/cache/tessera (a node's --scene-cache-dir) belong to
# tessera: a named volume mounted there starts as a copy of them, so it is writable with the root
# filesystem read-only.
RUN useradd --create-home --home-dir /home/tessera --uid 10001 --user-group tessera \
    && install -d -o tessera -g tessera /data /var/cache/tessera
COPY --from=builder /opt/venv /opt/venv
WORKDIR /app
# numba's compiled kernels (a node's frame resolve, the ingest's passes) are kept in the scene cache
# volume: the root filesystem is read-only, and without a writable cache every container start compiled
# them again (the resolve: 1.9 CPU-s compiled, 0.9 read from the cache). Where nothing writable is
# mounted there, numba falls back to $XDG_CACHE_HOME, or compiles.
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    NUMBA_CACHE_DIR=/var/cache/tessera/numba
USER tessera
EXPOSE 8000
CMD ["python", "-m", "server", "--host", "0.0.0.0"]
# The source last (owned by root, read-only to the tessera user): an edit rebuilds only these layers.
COPY tessera/ tessera/
COPY server/ server/
COPY node/ node/
COPY web/ web/
COPY docker/healthcheck.py docker/
