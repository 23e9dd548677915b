"""Which optional part of camcal (a pip "extra") a missing module belongs to.

``pip install camcal`` is what a module runs (`camcal lrm simulate|run|replay`,
the analysis, the simulator); the ship, PostgreSQL, Dask, Parquet, figures and
Mitsuba come with extras (``pyproject.toml``). A command that needs one which
is not installed ends with one line naming the extra to install, never a
traceback (`camcal.cli.main`).
"""

from __future__ import annotations

#: Top-level import name -> the extra that installs it.
EXTRA_OF_MODULE = {
    "fastapi": "ship",
    "fastapi_offline": "ship",
    "starlette": "ship",
    "uvicorn": "ship",
    "sqlalchemy": "ship",
    "alembic": "ship",
    "prometheus_client": "ship",
    "pydantic_settings": "ship",
    "plotly": "ship",
    "psycopg": "postgres",
    "psycopg_binary": "postgres",
    "dask": "scale",
    "distributed": "scale",
    "fsspec": "scale",
    "s3fs": "scale",
    "pyarrow": "export",
    "matplotlib": "plots",
    "mitsuba": "validate",
}


def missing_extra(exc: BaseException) -> str | None:
    """The one-line message for an import of an extra's module that failed, else None."""
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:  # the error itself, or what it was raised from
        seen.add(id(cur))
        if isinstance(cur, ModuleNotFoundError) and cur.name:
            top = cur.name.split(".")[0]
            extra = EXTRA_OF_MODULE.get(top)
            if extra is not None:
                return (
                    f"this command needs {top!r}, part of camcal's {extra!r} extra: "
                    f"pip install 'camcal[{extra}]' (or 'camcal[all]')"
                )
        cur = cur.__cause__ or cur.__context__
    return None
