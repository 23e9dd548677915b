"""Photon transport from the LEM to the cameras, and the templates built from it."""
