"""camcal's store: SQLAlchemy models (SQLite by default, any SQLAlchemy URL) and the frame files."""
