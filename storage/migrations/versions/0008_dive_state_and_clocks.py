"""A dive says why it ended

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-28 15:30:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("dives", schema=None) as batch_op:
        batch_op.add_column(sa.Column("end_reason", sa.String(length=300), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("dives", schema=None) as batch_op:
        batch_op.drop_column("end_reason")
