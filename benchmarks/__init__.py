"""Benchmarks of the integrators against Mitsuba's built-ins (``python -m benchmarks.speed``)."""
