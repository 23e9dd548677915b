"""The checksum of a data message's whole content (header fields and payload): a resend with another
header is a conflict

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-28 16:00:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None


def upgrade() -> None:
    for table in ("frames", "sensor_batches"):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.add_column(sa.Column("content_sha256", sa.String(length=64), nullable=True))


def downgrade() -> None:
    for table in ("sensor_batches", "frames"):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.drop_column("content_sha256")
