# camcal: the ship-side services (ingest, dashboard) and simulated modules.
# The same image runs every service of docker-compose.yml; each runs one
# `camcal` command, exactly as the README runs them without Docker.
FROM python:3.11-slim

ENV PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    CAMCAL_DATA_DIR=/data

WORKDIR /app
COPY pyproject.toml README.md ./
COPY camcal ./camcal
COPY analysis ./analysis
COPY lrm ./lrm
COPY ingest ./ingest
COPY storage ./storage
COPY server ./server
COPY frontend ./frontend
# The ship's extras (ingest, dashboard, store on PostgreSQL, export, figures, Dask); a module
# needs none of them (`pip install camcal`), and the simulated modules below run on the same image.
RUN pip install '.[ship,postgres,scale,export,plots]' && mkdir -p /data

EXPOSE 5555 5556 8000
VOLUME ["/data"]
ENTRYPOINT ["camcal"]
CMD ["--help"]
