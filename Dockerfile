# fleet-server image. Built and run with docker compose (see docker-compose.yml).

# The console's and /docs' third-party files (Leaflet, Swagger UI), pinned by the lock file.
FROM node:20-slim AS web
WORKDIR /web
COPY server/web/package.json server/web/package-lock.json ./
RUN npm ci --ignore-scripts --no-audit --no-fund

FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1
WORKDIR /app

COPY pyproject.toml README.md ./
COPY fleet_protocol ./fleet_protocol
COPY server ./server
COPY --from=web /web/node_modules ./server/web/node_modules
COPY vehicle_client ./vehicle_client
COPY remote_client ./remote_client
RUN pip install '.[server]'

RUN useradd --system --uid 10001 fleet && mkdir -p /data && chown fleet /data
USER fleet
ENV FLEET_HOST=0.0.0.0 FLEET_PORT=8000 FLEET_SNAPSHOT_PATH=/data/fleet-store.snapshot
EXPOSE 8000
HEALTHCHECK --interval=10s --timeout=3s --retries=3 \
  CMD python -c "import urllib.request,sys; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:8000/readyz', timeout=2).status == 200 else 1)"
CMD ["fleet-server"]
