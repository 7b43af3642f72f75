"""Figures and reports of a recording."""
