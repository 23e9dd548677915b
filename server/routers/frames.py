"""Frames: the filtered, paged list; one frame, its thumbnail, its image and its analysis."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import Response
from sqlalchemy.orm import Session

from camcal.core.files import write_atomic
from camcal.core.images import FrameReadError, decode_frame
from camcal.core.wire.image import ImageHeaderError, check_frame
from ingest.worker import thumbnail_jpeg
from server.deps import FloatQuery, IdPath, IdQuery, StoreDep, WavelengthQuery
from server.errors import Gone, Invalid, NotFound, Unreadable
from server.openapi import GONE, NOT_FOUND, UNREADABLE
from server.schemas import FrameAnalysis, FrameDetail, FramePage
from storage import queries
from storage.files import UnsafePath
from storage.store import Store

router = APIRouter(tags=["frames"])
STATUSES = "^(ok|rejected|pending)$"


def _urls(d: dict[str, Any]) -> dict[str, Any]:
    d["thumbnail_url"] = f"/api/frames/{d['id']}/thumbnail"
    d["image_url"] = f"/api/frames/{d['id']}/image"
    return d


@router.get("/api/frames", response_model=FramePage)
def list_frames(
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
    for lo, hi, names in (
        (depth_min_m, depth_max_m, ("depth_min_m", "depth_max_m")),
        (t_from, t_to, ("t_from", "t_to")),
    ):
        if lo is not None and hi is not None and lo > hi:
            raise Invalid(f"{names[0]} ({lo:g}) is above {names[1]} ({hi:g}): nothing could match; swap them")
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

    def q(s: Session) -> tuple[list[dict[str, Any]], int]:
        _, rid = queries.dive_and_run(s, dive, run)
        return queries.frames_page(s, f, rid, limit, offset, order)

    items, total = store.call(q)
    return {"items": [_urls(i) for i in items], "total": total, "limit": limit, "offset": offset}


def _frame(store: Store, frame_id: IdPath, run: int | None) -> dict[str, Any]:
    def q(s: Session) -> dict[str, Any] | None:
        found = queries.frame_with_result(s, frame_id, run)
        if found is not None and run is not None:
            queries.dive_and_run(s, found[0].dive_id, run)  # a run of its dive, else 404
        return queries.frame_dict(*found, full=True) if found is not None else None

    frame = store.call(q)
    if frame is None:
        raise NotFound(f"no frame {frame_id}")
    return _urls(frame)


@router.get("/api/frames/{frame_id}", response_model=FrameDetail)
def get_frame(frame_id: IdPath, store: StoreDep, run: IdQuery = None) -> dict[str, Any]:
    """One frame with its full analysis (profile and background fit included)."""
    return _frame(store, frame_id, run)


@router.get("/api/frames/{frame_id}/analysis", response_model=FrameAnalysis)
def frame_analysis(frame_id: IdPath, store: StoreDep, run: IdQuery = None) -> dict[str, Any]:
    """Centroid, radius, radial profile, background fit and I_center of a frame."""
    f = _frame(store, frame_id, run)
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


def _stored(store: Store, frame_id: int) -> tuple[str, int, int]:
    """The stored path, width and height of a frame (404 if there is no such frame)."""
    found = store.call(queries.frame_file, frame_id)
    if found is None:
        raise NotFound(f"no frame {frame_id}")
    return found


def _read(store: Store, frame_id: int, relative: str, under: str) -> bytes:
    """A file of the frame, read safely (`storage.files.FrameFiles.read_regular`)."""
    try:
        return store.files.read_regular(relative, under)
    except FileNotFoundError:
        raise Gone(
            f"frame {frame_id}: its file is no longer in the data folder (removed by retention?)"
        ) from None
    except UnsafePath as exc:
        raise NotFound(f"frame {frame_id} has no valid file: {exc}") from None


def _is_jpeg(data: bytes) -> bool:
    return data[:3] == b"\xff\xd8\xff" and data[-2:] == b"\xff\xd9"


FILE_CACHE = {"Cache-Control": "public, max-age=86400, immutable"}


@router.get(
    "/api/frames/{frame_id}/thumbnail",
    response_class=Response,
    responses={200: {"content": {"image/jpeg": {}}}, **NOT_FOUND, **GONE, **UNREADABLE},
)
def thumbnail(frame_id: IdPath, store: StoreDep) -> Response:
    """A 512 px JPEG of the frame, made once and cached in ``thumbs/<id>.jpg``.

    The frame must be in the database; the cached file is read without
    following symbolic links and served only if it is a JPEG (else it is
    made again from the frame).
    """

    return Response(_thumbnail(store, frame_id), media_type="image/jpeg", headers=FILE_CACHE)


def _thumbnail(store: Store, frame_id: int) -> bytes:
    relative, width, height = _stored(store, frame_id)
    thumb = f"thumbs/{frame_id}.jpg"
    try:
        cached = store.files.read_regular(thumb, "thumbs")
        if _is_jpeg(cached):
            return cached
    except (FileNotFoundError, UnsafePath):
        pass
    data = _read(store, frame_id, relative, "frames")
    _check_image(frame_id, relative, data, width, height)
    try:
        jpeg = thumbnail_jpeg(decode_frame(data, relative))
    except FrameReadError as exc:
        raise Unreadable(f"frame {frame_id}: {exc.detail}") from None
    path = store.files.root / "thumbs" / f"{frame_id}.jpg"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, jpeg, fsync=False)  # a rename: replaces a link, never writes through one
    except OSError:  # a full disk: served all the same, made again next time
        pass
    return jpeg


def _check_image(frame_id: int, relative: str, data: bytes, width: int, height: int) -> str:
    """The media type of a frame file, if it is the 8-bit grey PNG or TIFF its row says; else 422."""
    encoding = "tiff" if relative.endswith(".tif") else "png"
    try:
        check_frame(data, encoding, width, height)
    except ImageHeaderError as exc:
        raise Unreadable(f"frame {frame_id}: its file is not the image it claims to be ({exc})") from None
    return "image/tiff" if encoding == "tiff" else "image/png"


@router.get(
    "/api/frames/{frame_id}/image",
    response_class=Response,
    responses={200: {"content": {"image/png": {}, "image/tiff": {}}}, **NOT_FOUND, **GONE, **UNREADABLE},
)
def image(frame_id: IdPath, store: StoreDep) -> Response:
    """The full frame as stored (lossless PNG, exactly the module's bytes).

    Read without following symbolic links, and served only if it is the
    8-bit grey PNG (or TIFF) of the size its row says.
    """

    relative, width, height = _stored(store, frame_id)
    data = _read(store, frame_id, relative, "frames")
    media = _check_image(frame_id, relative, data, width, height)
    return Response(data, media_type=media, headers=FILE_CACHE)
