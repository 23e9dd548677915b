"""A dive says why it ended; one clock per dive: the ship's times of the modules' frames, samples and
λ_att points, and each module's clock (rate, anchor, offset) per boot

Revision ID: 0010
Revises: 0009
Create Date: 2026-11-28 15:30:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0010"
down_revision = "0009"
branch_labels = None
depends_on = None

#: Tables whose module times get a ship's time beside them (None before: the module's time stands).
SHIP_TIMES = {
    "frames": "captured_ship_unix_s",
    "sensor_samples": "t_ship_unix_s",
    "attitude_samples": "t_ship_unix_s",
    "attenuation_points": "t_ship_unix_s",
}


def upgrade() -> None:
    with op.batch_alter_table("dives", schema=None) as batch_op:
        batch_op.add_column(sa.Column("end_reason", sa.String(length=300), nullable=True))
    for table, column in SHIP_TIMES.items():
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.add_column(sa.Column(column, sa.Float(), nullable=True))
    # A frame stored before has no mapping: its module's time stands for the ship's (the frame
    # browser and the timeline order and filter on this column, with an index).
    op.execute("UPDATE frames SET captured_ship_unix_s = captured_unix_s")
    op.create_index("ix_frames_dive_ship_time", "frames", ["dive_id", "captured_ship_unix_s"])
    op.create_table(
        "module_clocks",
        sa.Column(
            "id", sa.BigInteger().with_variant(sa.Integer(), "sqlite"), autoincrement=True, nullable=False
        ),
        sa.Column("dive_id", sa.BigInteger().with_variant(sa.Integer(), "sqlite"), nullable=True),
        sa.Column("module_id", sa.String(length=64), nullable=False),
        sa.Column("boot", sa.String(length=64), nullable=False),
        sa.Column("rate", sa.Float(), nullable=False),
        sa.Column("module_at_unix_s", sa.Float(), nullable=False),
        sa.Column("real_at_unix_s", sa.Float(), nullable=False),
        sa.Column("offset_s", sa.Float(), nullable=True),
        sa.Column("n_readings", sa.Integer(), nullable=False),
        sa.Column("first_unix_s", sa.Float(), nullable=False),
        sa.Column("updated_unix_s", sa.Float(), nullable=False),
        sa.ForeignKeyConstraint(["dive_id"], ["dives.id"]),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("module_id", "boot", name="uq_module_clocks"),
    )


def downgrade() -> None:
    op.drop_table("module_clocks")
    op.drop_index("ix_frames_dive_ship_time", table_name="frames")
    for table, column in SHIP_TIMES.items():
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.drop_column(column)
    with op.batch_alter_table("dives", schema=None) as batch_op:
        batch_op.drop_column("end_reason")
