"""Modules say what their camera is and can take (protocol revision 1.8): kept with the module

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-28 15:00:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("modules", schema=None) as batch_op:
        batch_op.add_column(sa.Column("camera_json", sa.Text(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("modules", schema=None) as batch_op:
        batch_op.drop_column("camera_json")
