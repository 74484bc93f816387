"""Smoothing, tables and figures over results on disk (pandas frames; no package internals needed)."""
