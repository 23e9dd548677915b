"""λ_att points per LEM visit: visit key, span, frames used, provisional/final

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-26 03:00:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("attenuation_points", schema=None) as batch_op:
        batch_op.add_column(sa.Column("visit_key", sa.String(length=80), nullable=True))
        batch_op.add_column(sa.Column("t_first_unix_s", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("t_last_unix_s", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("n_frames", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("final", sa.Boolean(), server_default=sa.text("true"), nullable=False))
        batch_op.create_index("ux_att_run_visit", ["run_id", "visit_key"], unique=True)


def downgrade() -> None:
    with op.batch_alter_table("attenuation_points", schema=None) as batch_op:
        batch_op.drop_index("ux_att_run_visit")
        batch_op.drop_column("final")
        batch_op.drop_column("n_frames")
        batch_op.drop_column("t_last_unix_s")
        batch_op.drop_column("t_first_unix_s")
        batch_op.drop_column("visit_key")
