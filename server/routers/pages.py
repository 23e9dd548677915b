"""The dashboard's pages and assets, and plotly.js from the installed plotly package, gzipped."""

from __future__ import annotations

import gzip
import hashlib
from functools import lru_cache
from pathlib import Path

import plotly
from fastapi import APIRouter, Request
from fastapi.responses import FileResponse, Response

from frontend import STATIC_DIR
from server.errors import NotFound

router = APIRouter(include_in_schema=False)


@lru_cache(maxsize=1)
def plotly_assets() -> tuple[bytes, bytes, str]:
    """plotly.min.js, its gzip and an ETag: compressed once, served many times."""
    path = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
    data = path.read_bytes()
    return data, gzip.compress(data, compresslevel=6), hashlib.sha256(data).hexdigest()[:16]


@router.get("/vendor/plotly.min.js")
def plotly_js(request: Request) -> Response:
    data, packed, etag = plotly_assets()
    headers = {"Cache-Control": "public, max-age=604800", "ETag": f'"{etag}"', "Vary": "Accept-Encoding"}
    if request.headers.get("if-none-match") == f'"{etag}"':
        return Response(status_code=304, headers=headers)
    if "gzip" in request.headers.get("accept-encoding", ""):
        return Response(
            packed, media_type="application/javascript", headers={**headers, "Content-Encoding": "gzip"}
        )
    return Response(data, media_type="application/javascript", headers=headers)


def _page(name: str) -> FileResponse:
    path = STATIC_DIR / name
    if not path.is_file():
        raise NotFound(f"page {name} is missing from the installation")
    return FileResponse(path, media_type="text/html", headers={"Cache-Control": "no-cache"})


@router.get("/")
def live_page() -> FileResponse:
    return _page("live.html")


@router.get("/review")
def review_page() -> FileResponse:
    return _page("review.html")


@router.get("/control")
def control_page() -> FileResponse:
    return _page("control.html")
