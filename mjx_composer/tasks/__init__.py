"""Bundled example tasks."""
