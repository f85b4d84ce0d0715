"""Evaluating a run file into key figures: one module per procedure family, then suitability."""
