# fpv-station: one image for the Raspberry Pi (linux/arm64) and laptops (linux/amd64).
#   docker buildx build --platform linux/arm64,linux/amd64 -t fpv-station .
#
# On the Pi, pass the Pixhawk's serial port and the two USB video grabbers through:
#   docker run --rm -p 8000:8000 -p 8080:8080 \
#     --device /dev/serial0 --device /dev/video0 --device /dev/video2 \
#     -v /home/pi/sessions:/data/sessions \
#     fpv-station serve --source /dev/serial0:921600 \
#       --front v4l2:/dev/video0 --bottom v4l2:/dev/video2
# With no arguments it starts on the embedded digital twin.
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1
WORKDIR /app
COPY pyproject.toml README.md ./
COPY server ./server
COPY companion ./companion
COPY twin ./twin
COPY analysis ./analysis
COPY web ./web
RUN pip install .

# 8000: web UI, REST, WebSocket, MJPEG; 8080: the viser 3D panel
EXPOSE 8000 8080
ENTRYPOINT ["fpv-station"]
CMD ["serve", "--source", "sim", "--host", "0.0.0.0"]
