"""Sampling strategies of the lecture, shared by the plugins."""
