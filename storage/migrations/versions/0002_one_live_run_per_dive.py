"""one live run per dive, enforced by the database

Several ingest processes share one database (each serving some modules);
all of them record into the dive's single ``live`` run. A partial unique
index makes "get or create the live run" safe under concurrency: the losing
insert does nothing and reads the winner's row. A database that already
holds two live runs for a dive keeps the oldest as ``live`` and renames the
others ``live-extra`` (their results stay).

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-23 10:00:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None

LIVE = sa.text("kind = 'live'")


def upgrade() -> None:
    op.execute(
        "UPDATE analysis_runs SET kind = 'live-extra' WHERE kind = 'live' AND id NOT IN "
        "(SELECT min_id FROM (SELECT MIN(id) AS min_id FROM analysis_runs "
        "WHERE kind = 'live' GROUP BY dive_id) AS firsts)"
    )
    op.create_index(
        "uq_analysis_runs_live",
        "analysis_runs",
        ["dive_id"],
        unique=True,
        sqlite_where=LIVE,
        postgresql_where=LIVE,
    )


def downgrade() -> None:
    op.drop_index("uq_analysis_runs_live", table_name="analysis_runs")
