# dcseg API: slim Python, no torch, no CUDA. Build from the repository root:
#   docker build -f docker/api.Dockerfile -t dcseg-api .
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    DCSEG_STORAGE_DIR=/data

WORKDIR /app
RUN groupadd --system dcseg && useradd --system --gid dcseg --home-dir /app dcseg

# Dependencies first (cached layer); the project itself with --no-deps keeps torch out.
COPY docker/api-requirements.txt /tmp/api-requirements.txt
RUN pip install -r /tmp/api-requirements.txt

COPY pyproject.toml README.md ./
COPY dcseg ./dcseg
COPY service ./service
COPY worker ./worker
RUN pip install --no-deps . \
    && python -c "import sys, service.main; assert 'torch' not in sys.modules" \
    && mkdir -p /data && chown dcseg:dcseg /data

USER dcseg
VOLUME ["/data"]
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"]
# One process: the rate limiter is per process; scale with replicas behind a proxy.
CMD ["uvicorn", "service.main:app", "--host", "0.0.0.0", "--port", "8000", "--proxy-headers"]
