# The advice service: `docker build -t advisor . && docker run -p 127.0.0.1:8000:8000 \
#   -v advisor-data:/data advisor`  (API on 8000). The viser viewer (its own process, port 8080)
# listens on the container's loopback only: it shows where explorers are and asks a browser for
# no key. To reach it from the host, add `-e ADVISOR_VIEWER_HOST=0.0.0.0 -p 127.0.0.1:8080:8080`
# (publish it on the host's loopback, as here, never on a public interface) and open
# http://127.0.0.1:8080/ or http://localhost:8080/ (on 0.0.0.0 it takes pages of the loopback
# names at its port; a page of any other origin is refused). Published on another host port,
# name that page's origin: `-p 127.0.0.1:9090:8080 -e ADVISOR_VIEWER_ORIGINS='["http://127.0.0.1:9090"]'`.
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    ADVISOR_HOST=0.0.0.0 \
    ADVISOR_DATA_DIR=/data \
    ADVISOR_STATIC_DIR=/app/static \
    NUMBA_CACHE_DIR=/home/advisor/.cache/numba \
    MPLCONFIGDIR=/home/advisor/.cache/matplotlib

WORKDIR /app

# dependencies first (a layer that survives code changes), then the client (client/, its own
# distribution, which the service's requires) and the package itself
COPY pyproject.toml README.md ./
RUN python -c "import tomllib; print('\n'.join(d for d in tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies'] if not d.startswith('hidden-goal-advisor-client')))" > /tmp/requirements.txt \
    && pip install -r /tmp/requirements.txt \
    && rm /tmp/requirements.txt
COPY client ./client
RUN pip install --no-deps ./client
COPY app ./app
COPY static ./static
RUN pip install --no-deps . \
    && useradd --create-home --uid 10001 advisor \
    && mkdir -p /data \
    && chown advisor:advisor /data

USER advisor
# compile the service's numba loop once, into the image (startup then only loads it)
RUN python -c "from app.service.ops import warm_up; warm_up()"

VOLUME ["/data"]
EXPOSE 8000
# liveness: the process answers (a database or Redis that is down makes /health/ready 503,
# which is for load balancers; restarting the container would not bring them back)
HEALTHCHECK --interval=30s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(urllib.request.urlopen('http://127.0.0.1:8000/health/live', timeout=4).status != 200)"]
CMD ["python", "-m", "app", "serve", "--host", "0.0.0.0", "--port", "8000"]
