"""Derived data from a store: ParaView time series, the model over the video, figures, tables."""
