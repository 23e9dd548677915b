"""The ship side: receive frames and sensor packets, store them, analyse them, publish events."""
