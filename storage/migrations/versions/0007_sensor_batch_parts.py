"""A large sensor batch is stored a part per turn: its samples name their batch, the batch says when
it is complete

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-28 10:00:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("sensor_batches", schema=None) as batch_op:
        batch_op.add_column(
            sa.Column("complete", sa.Boolean(), server_default=sa.text("true"), nullable=False)
        )
    with op.batch_alter_table("sensor_samples", schema=None) as batch_op:
        batch_op.add_column(sa.Column("batch_id", sa.BigInteger(), nullable=True))
        batch_op.create_index("ix_sensor_samples_batch_id", ["batch_id"], unique=False)


def downgrade() -> None:
    with op.batch_alter_table("sensor_samples", schema=None) as batch_op:
        batch_op.drop_index("ix_sensor_samples_batch_id")
        batch_op.drop_column("batch_id")
    with op.batch_alter_table("sensor_batches", schema=None) as batch_op:
        batch_op.drop_column("complete")
