"""Simulation against measurement: name, fit and add the effects a model misses (docs/reconcile.md)."""
