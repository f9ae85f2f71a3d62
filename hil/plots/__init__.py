"""Figures (matplotlib, Agg canvas: no display and no pyplot global state, safe in threads and tests)."""
