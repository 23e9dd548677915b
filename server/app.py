"""The FastAPI application, built by a factory: nothing is created at import."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.middleware.gzip import GZipMiddleware
from fastapi.staticfiles import StaticFiles

from camcal import __version__
from frontend import STATIC_DIR
from server import errors
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
            st, settings.events, client_queue=settings.client_queue, station_depth_m=settings.station_depth_m
        )
        app.state.store, app.state.hub = st, hub
        hub.start(asyncio.get_running_loop())
        try:
            yield
        finally:
            hub.stop()
            if own:
                st.close()

    app = FastAPI(
        title="camcal",
        version=__version__,
        description="Camera-based optical calibration: live deck view, dive review and control.",
        lifespan=lifespan,
    )
    app.state.settings = settings
    errors.install(app)
    app.add_middleware(GZipMiddleware, minimum_size=2048)
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
