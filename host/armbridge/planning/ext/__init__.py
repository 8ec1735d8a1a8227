"""Compiled extensions over system libraries the PyPI wheels lack (built on first use: ext.build)."""
