"""sensor batch checksums (to tell a resend from a conflict) and counters that survive restarts

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-25 03:00:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("sensor_batches", schema=None) as batch_op:
        batch_op.add_column(sa.Column("sha256", sa.String(length=64), nullable=True))
    op.create_table(
        "ingest_counters",
        sa.Column("ingest_id", sa.String(length=200), nullable=False),
        sa.Column("name", sa.String(length=120), nullable=False),
        sa.Column("value", sa.BigInteger(), nullable=False),
        sa.Column("updated_unix_s", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint("ingest_id", "name"),
    )


def downgrade() -> None:
    op.drop_table("ingest_counters")
    with op.batch_alter_table("sensor_batches", schema=None) as batch_op:
        batch_op.drop_column("sha256")
