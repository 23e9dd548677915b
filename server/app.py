"""The FastAPI application, built by a factory: nothing is created at import."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.middleware.gzip import GZipMiddleware
from fastapi.staticfiles import StaticFiles

from camcal.core import __version__
from frontend import STATIC_DIR
from server import errors, openapi
from server.guard import Guard, TokenThrottle
from server.jobs import ExportSlots, PreviewSlots, ReanalysisQueue
from server.relay import LiveHub
from server.routers import (
    alarms,
    calibrations,
    control,
    dives,
    frames,
    health,
    live,
    metrics,
    operator,
    pages,
    series,
)
from server.saturation import SaturationByDesign
from server.settings import ServerSettings
from storage.store import Store


def create_app(settings: ServerSettings | None = None, *, store: Store | None = None) -> FastAPI:
    """A new app for ``settings``; the store and the live hub open in its lifespan.

    Pass ``store`` to share one already open (tests); otherwise the app opens
    the data folder's store when it starts and closes it when it stops.
    """
    settings = settings or ServerSettings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        own = store is None
        st = store or Store.open(settings.data_dir, settings.db_url, run_migrations=settings.run_migrations)
        hub = LiveHub(
            st,
            settings.events,
            client_queue=settings.client_queue,
            station_depth_m=settings.station_depth_m,
            saturation=SaturationByDesign(st, settings.linear_range),
            keys_dir=settings.keys_dir,
            events_curve=settings.events_curve,
        )
        app.state.store, app.state.hub = st, hub
        app.state.reanalyses = ReanalysisQueue(st, settings.max_reanalyses_queued)
        hub.start(asyncio.get_running_loop())
        try:
            yield
        finally:
            hub.stop()
            app.state.reanalyses.stop()
            if own:
                st.close()

    app = FastAPI(
        title="camcal",
        version=__version__,
        description="Camera-based optical calibration: live deck view, dive review and control.",
        lifespan=lifespan,
        docs_url=None,  # served by `server.routers.pages` from installed files, never from a CDN
        redoc_url=None,
    )
    app.state.settings = settings
    app.state.throttle = TokenThrottle(settings.token_failures, settings.token_window_s)
    app.state.exports = ExportSlots(settings.exports_at_once)
    app.state.previews = PreviewSlots(settings.previews_at_once, settings.operator_previews_at_once)
    errors.install(app)
    openapi.install(app)
    app.add_middleware(GZipMiddleware, minimum_size=2048)
    app.add_middleware(Guard, fastapi_app=app)  # outermost: every response gets its headers
    for r in (
        health.router,
        dives.router,
        frames.router,
        series.router,
        alarms.router,
        control.router,
        calibrations.router,
        metrics.router,
        live.router,
        operator.router,
        pages.router,
    ):
        app.include_router(r)
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    return app
