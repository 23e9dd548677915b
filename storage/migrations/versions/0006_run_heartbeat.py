"""Re-analysis runs beat: a run whose process stopped reads as interrupted, not running forever

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-27 11:40:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("analysis_runs", schema=None) as batch_op:
        batch_op.add_column(sa.Column("heartbeat_unix_s", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("owner", sa.String(length=200), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("analysis_runs", schema=None) as batch_op:
        batch_op.drop_column("owner")
        batch_op.drop_column("heartbeat_unix_s")
