"""Frames: the filtered, paged list; one frame, its thumbnail, its image and its analysis."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, Response

from camcal.frameset import FrameReadError, read_frame, write_atomic
from ingest.worker import thumbnail_jpeg
from server.deps import FloatQuery, IdPath, IdQuery, StoreDep, WavelengthQuery
from server.errors import Gone, NotFound, Unreadable
from server.schemas import FramePage
from storage import queries
from storage.files import UnsafePath

router = APIRouter(tags=["frames"])
STATUSES = "^(ok|rejected|pending)$"


def _urls(d: dict[str, Any]) -> dict[str, Any]:
    d["thumbnail_url"] = f"/api/frames/{d['id']}/thumbnail"
    d["image_url"] = f"/api/frames/{d['id']}/image"
    return d


@router.get("/api/frames", response_model=FramePage)
async def list_frames(
    store: StoreDep,
    dive: IdQuery = None,
    module: Annotated[str | None, Query(max_length=64)] = None,
    wavelength_nm: WavelengthQuery = None,
    exposure_s: FloatQuery = None,
    gain_db: FloatQuery = None,
    status: Annotated[str | None, Query(pattern=STATUSES)] = None,
    reason: Annotated[str | None, Query(max_length=32)] = None,
    t_from: FloatQuery = None,
    t_to: FloatQuery = None,
    depth_min_m: FloatQuery = None,
    depth_max_m: FloatQuery = None,
    run: IdQuery = None,
    order: Annotated[str, Query(pattern="^(time|newest)$")] = "time",
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Query(ge=0, le=10_000_000)] = 0,
) -> dict[str, Any]:
    """Frames with their result (in the live run, or ``run``), filtered and paged."""
    f = queries.FrameFilter(
        dive,
        module,
        wavelength_nm,
        exposure_s,
        gain_db,
        status,
        reason,
        t_from,
        t_to,
        depth_min_m,
        depth_max_m,
    )

    def q() -> dict[str, Any]:
        with store.read() as s:
            dive_id = dive if dive is not None else (queries.dives(s) or [{"id": None}])[0]["id"]
            rid = run or (queries.live_run_id(s, dive_id) if dive_id is not None else None)
            items, total = queries.frames_page(s, f, rid, limit, offset, order)
        return {"items": [_urls(i) for i in items], "total": total, "limit": limit, "offset": offset}

    return await run_in_threadpool(q)


def _frame(store: Any, frame_id: IdPath, run: int | None) -> dict[str, Any]:
    with store.read() as s:
        found = queries.frame_with_result(s, frame_id, run)
        if found is None:
            raise NotFound(f"no frame {frame_id}")
        return _urls(queries.frame_dict(*found, full=True))


@router.get("/api/frames/{frame_id}")
async def get_frame(frame_id: IdPath, store: StoreDep, run: IdQuery = None) -> dict[str, Any]:
    """One frame with its full analysis (profile and background fit included)."""
    return await run_in_threadpool(_frame, store, frame_id, run)


@router.get("/api/frames/{frame_id}/analysis")
async def frame_analysis(frame_id: IdPath, store: StoreDep, run: IdQuery = None) -> dict[str, Any]:
    """Centroid, radius, radial profile, background fit and I_center of a frame."""
    f = await run_in_threadpool(_frame, store, frame_id, run)
    keys = (
        "id",
        "status",
        "reason",
        "detail",
        "centroid_px",
        "radius_px",
        "elongation",
        "center_gray",
        "center_err_gray",
        "background_gray",
        "background_err_gray",
        "i_center_gray",
        "i_center_err_gray",
        "profile",
        "fit",
        "run_id",
    )
    return {k: f.get(k) for k in keys}


def _file_there(path: Path) -> bool:
    try:
        return path.is_file()
    except OSError:  # a name the file system cannot hold
        return False


def _stored_path(store: Any, frame_id: IdPath) -> tuple[Path, Path]:
    with store.read() as s:
        found = queries.frame_with_result(s, frame_id, None)
    if found is None:
        raise NotFound(f"no frame {frame_id}")
    try:
        image = store.files.resolve(found[0].path)
    except UnsafePath:
        raise NotFound(f"frame {frame_id} has no valid file") from None
    return image, store.files.root / "thumbs" / f"{frame_id}.jpg"


@router.get(
    "/api/frames/{frame_id}/thumbnail",
    response_class=Response,
    responses={200: {"content": {"image/jpeg": {}}}},
)
async def thumbnail(frame_id: IdPath, store: StoreDep) -> Response:
    """A 512 px JPEG of the frame, made once and cached.

    A cached thumbnail is served straight from ``thumbs/<id>.jpg`` (the id is
    an integer, so the name cannot leave that folder) without a database
    query: every live browser asks for every new one.
    """
    headers = {"Cache-Control": "public, max-age=86400, immutable"}
    cached = store.files.root / "thumbs" / f"{frame_id}.jpg"
    try:
        return Response(cached.read_bytes(), media_type="image/jpeg", headers=headers)
    except FileNotFoundError:
        pass

    def make() -> bytes:
        image, thumb = _stored_path(store, frame_id)
        if thumb.exists():
            return thumb.read_bytes()
        if not _file_there(image):
            raise Gone(f"frame {frame_id}: its file is no longer in the data folder (removed by retention?)")
        try:
            data = thumbnail_jpeg(read_frame(image))
        except FrameReadError as exc:
            raise Unreadable(f"frame {frame_id}: {exc.detail}") from None
        thumb.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(thumb, data, fsync=False)
        return data

    data = await run_in_threadpool(make)
    return Response(data, media_type="image/jpeg", headers=headers)


@router.get(
    "/api/frames/{frame_id}/image",
    response_class=FileResponse,
    responses={200: {"content": {"image/png": {}}}},
)
async def image(frame_id: IdPath, store: StoreDep) -> FileResponse:
    """The full frame as stored (lossless PNG, exactly the module's bytes)."""
    path, _ = await run_in_threadpool(_stored_path, store, frame_id)
    if not _file_there(path):
        raise Gone(f"frame {frame_id}: its file is no longer in the data folder (removed by retention?)")
    media = "image/tiff" if path.suffix == ".tif" else "image/png"
    return FileResponse(path, media_type=media, headers={"Cache-Control": "public, max-age=86400, immutable"})
