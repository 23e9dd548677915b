"""The dashboard's pages and assets: plotly.js from the installed plotly package, gzipped, and the
API's documentation pages (/docs: Swagger UI, /redoc: ReDoc) with their scripts and styles from the
installed ``fastapi-offline`` package: nothing is fetched from a CDN, so the pages work on a ship
without internet and no third-party code runs on the origin that holds the operator token."""

from __future__ import annotations

import gzip
import hashlib
from functools import lru_cache
from pathlib import Path

import fastapi_offline
import plotly
from fastapi import APIRouter, Request
from fastapi.responses import FileResponse, HTMLResponse, Response

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
    return _cached(request, plotly_assets(), "application/javascript")


#: The documentation pages' assets, by the name they are served under.
DOCS_ASSETS = {
    "swagger-ui-bundle.js": "application/javascript",
    "swagger-ui.css": "text/css",
    "redoc.standalone.js": "application/javascript",
}


#: What the documentation assets would fetch from elsewhere, and what they ask for instead: ReDoc's
#: menu footer shows Redocly's logo from their CDN (the policy blocks it; the browser says so in its
#: console). ``data:,`` is no image: the footer's own error handler drops the logo, its text stays.
OFFLINE = {"redoc.standalone.js": ((b"https://cdn.redoc.ly/redoc/logo-mini.svg", b"data:,"),)}


@lru_cache(maxsize=len(DOCS_ASSETS))
def docs_asset(name: str) -> tuple[bytes, bytes, str]:
    path = Path(fastapi_offline.__file__).parent / "static" / name
    data = path.read_bytes()
    for remote, local in OFFLINE.get(name, ()):
        data = data.replace(remote, local)
    return data, gzip.compress(data, compresslevel=6), hashlib.sha256(data).hexdigest()[:16]


def _cached(request: Request, asset: tuple[bytes, bytes, str], media: str) -> Response:
    data, packed, etag = asset
    headers = {"Cache-Control": "public, max-age=604800", "ETag": f'"{etag}"', "Vary": "Accept-Encoding"}
    if request.headers.get("if-none-match") == f'"{etag}"':
        return Response(status_code=304, headers=headers)
    if "gzip" in request.headers.get("accept-encoding", ""):
        return Response(packed, media_type=media, headers={**headers, "Content-Encoding": "gzip"})
    return Response(data, media_type=media, headers=headers)


@router.get("/vendor/docs/{name}")
def docs_file(name: str, request: Request) -> Response:
    media = DOCS_ASSETS.get(name)
    if media is None:
        raise NotFound(f"no documentation asset {name!r}")
    return _cached(request, docs_asset(name), media)


_DOCS_HEAD = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>camcal API · {title}</title>
<meta name="viewport" content="width=device-width, initial-scale=1"><link rel="icon" href="data:,">
{head}</head><body>{body}</body></html>
"""


@router.get("/docs", response_class=HTMLResponse)
def swagger_ui() -> HTMLResponse:
    head = '<link rel="stylesheet" href="/vendor/docs/swagger-ui.css">'
    body = (
        '<div id="swagger-ui"></div><script src="/vendor/docs/swagger-ui-bundle.js"></script>'
        '<script src="/static/js/docs-swagger.js"></script>'
    )
    return HTMLResponse(_DOCS_HEAD.format(title="Swagger UI", head=head, body=body))


@router.get("/redoc", response_class=HTMLResponse)
def redoc() -> HTMLResponse:
    body = '<redoc spec-url="/openapi.json"></redoc><script src="/vendor/docs/redoc.standalone.js"></script>'
    return HTMLResponse(_DOCS_HEAD.format(title="ReDoc", head="", body=body))


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
