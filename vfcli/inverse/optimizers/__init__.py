"""Optimisers of the control values: one base with the bookkeeping, one step per method."""
