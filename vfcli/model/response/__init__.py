"""Responses: maps from control values to vertex displacements over time."""
