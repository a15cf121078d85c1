# The morphmimic image: CPU torch, MuJoCo rendering headless through Mesa's EGL, this repository
# installed as the README installs it, at /app (deploy/kuberay.yaml runs its pods there).
#
#   docker build -t your-registry/morphmimic:0.1.0 .
#   docker push your-registry/morphmimic:0.1.0
#
# (your-registry: your own registry, here and in deploy/kuberay.yaml; the tag is pyproject's
# version, checked by tests/test_release.py.)
FROM python:3.11-slim-bookworm

# Offscreen rendering (the EGL packages `.ci/run` installs) and wget, which KubeRay's readiness
# and liveness probes run in every Ray container.
RUN apt-get update \
 && apt-get install -y --no-install-recommends libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri wget \
 && rm -rf /var/lib/apt/lists/*

ENV MUJOCO_GL=egl \
    PYOPENGL_PLATFORM=egl \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

WORKDIR /app

# torch first from PyTorch's CPU index (PyPI's default is a several-GB CUDA build), in its own
# layer so that a code change does not download it again.
RUN pip install "torch>=2.4,<2.14" --index-url https://download.pytorch.org/whl/cpu

COPY . /app
RUN pip install -e . && morphmimic --version

CMD ["python", "-m", "learner.main"]
