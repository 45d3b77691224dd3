# undertow: the planning service (uvicorn on 0.0.0.0:8000, job store on the /data volume).
#
#   bash docker/build-base.sh          # the base image: pulled, or built locally if air-gapped
#   DOCKER_BUILDKIT=1 docker build -t undertow \
#       --secret id=ca_bundle,src=/etc/ssl/certs/ca-certificates.crt .
#
# BASE_IMAGE may be any Debian-based image with python3 >= 3.11 and its venv module.
# Optional build secrets, never stored in a layer: ca_bundle (a CA bundle for pip when a
# TLS-inspecting proxy sits between the build and the package index) and pip_conf (a
# pip.conf naming a package index mirror). See docs/deploy.md.
ARG BASE_IMAGE=python:3.11-slim

FROM ${BASE_IMAGE} AS builder
ENV PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PYTHONDONTWRITEBYTECODE=1
RUN python3 -m venv /opt/venv
WORKDIR /src
COPY requirements/runtime.txt requirements/
# Dependencies first, in their own layer: a change to the code alone reuses it. The lock
# file pins them (`make lock` regenerates it from pyproject.toml).
RUN --mount=type=secret,id=ca_bundle,required=false \
    --mount=type=secret,id=pip_conf,required=false \
    if [ -s /run/secrets/ca_bundle ]; then export PIP_CERT=/run/secrets/ca_bundle; fi \
    && if [ -s /run/secrets/pip_conf ]; then export PIP_CONFIG_FILE=/run/secrets/pip_conf; fi \
    && /opt/venv/bin/pip install --no-cache-dir -r requirements/runtime.txt
COPY pyproject.toml README.md ./
COPY planner/ planner/
COPY app/ app/
RUN --mount=type=secret,id=ca_bundle,required=false \
    --mount=type=secret,id=pip_conf,required=false \
    if [ -s /run/secrets/ca_bundle ]; then export PIP_CERT=/run/secrets/ca_bundle; fi \
    && if [ -s /run/secrets/pip_conf ]; then export PIP_CONFIG_FILE=/run/secrets/pip_conf; fi \
    && /opt/venv/bin/pip install --no-cache-dir --no-deps . \
    && /opt/venv/bin/pip check

FROM ${BASE_IMAGE} AS runtime
RUN groupadd --gid 10001 undertow \
    && useradd --uid 10001 --gid undertow --no-create-home \
       --home-dir /nonexistent --shell /usr/sbin/nologin undertow \
    && mkdir /data \
    && chown undertow:undertow /data
COPY --from=builder /opt/venv /opt/venv
WORKDIR /srv/undertow
# One uvicorn process per container: scale solves with UNDERTOW_WORKERS (processes) and
# the service with more containers. UNDERTOW_INSTANCE names this server in the job store;
# it stays fixed across container re-creation so that jobs a stopped container left
# running are marked interrupted when it comes back. The same image runs either role on a
# shared PostgreSQL store (UNDERTOW_DB_URL): an API-only server (UNDERTOW_WORKERS=0) or,
# with the command `undertow worker`, a worker node (compose.yaml, docs/deploy.md).
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    MPLCONFIGDIR=/tmp/matplotlib \
    UNDERTOW_DB_PATH=/data/undertow-jobs.sqlite3 \
    UNDERTOW_INSTANCE=undertow \
    UNDERTOW_WORKERS=2
VOLUME ["/data"]
USER 10001:10001
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"]
CMD ["uvicorn", "app.main:app", "--host", "0.0.0.0", "--port", "8000", "--http", "app.server:HeadTimeoutProtocol"]
