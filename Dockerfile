# fpv-station: one image for the Raspberry Pi (linux/arm64) and laptops (linux/amd64).
#   docker buildx build --platform linux/arm64,linux/amd64 -t fpv-station .
# On the Pi use deploy/compose.yaml (serial port, cameras, sessions volume, restart policy):
#   docker compose -f deploy/compose.yaml up -d
# With no arguments it starts on the embedded digital twin.
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1
WORKDIR /app
COPY pyproject.toml README.md ./
# Every folder pyproject.toml installs ([tool.setuptools.package-dir]).
COPY fpv_station ./fpv_station
COPY core ./core
COPY companion ./companion
COPY twin ./twin
COPY analysis ./analysis
COPY server ./server
COPY learn ./learn
COPY web ./web
RUN pip install .

# Not root: a user in dialout (serial) and video (V4L2), the groups' Debian ids, which
# Raspberry Pi OS shares (20 and 44), so --device nodes from the host are usable.
RUN useradd --system --uid 999 --user-group --groups dialout,video \
        --home-dir /data --shell /usr/sbin/nologin fpv-station \
    && mkdir -p /data/sessions && chown -R fpv-station:fpv-station /data
USER fpv-station
ENV HOME=/data FPV_RECORDING__SESSIONS_DIR=/data/sessions FPV_SERVER__TOKEN_FILE=/data/token
VOLUME /data

# 8000: web UI, REST, WebSocket, MJPEG and the 3D panels (/3d/live, /3d/replay: their viser
# servers listen inside the container only, on loopback)
EXPOSE 8000
HEALTHCHECK --interval=15s --timeout=5s --start-period=30s --retries=3 CMD \
    python -c "import json,sys,urllib.request as u; \
sys.exit(0 if json.load(u.urlopen('http://127.0.0.1:8000/api/health', timeout=4))['ok'] else 1)"
ENTRYPOINT ["fpv-station"]
CMD ["serve", "--source", "sim", "--host", "0.0.0.0"]
