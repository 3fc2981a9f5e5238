"""Adapters: other solvers' problems as pdestream entries (each imports its solver lazily: an optional dependency)."""
