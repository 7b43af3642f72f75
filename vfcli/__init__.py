"""vfcli: physically valid 3D vocal-fold motion from high-speed video, vibrometry and pressure."""

__version__ = "0.1.0"
