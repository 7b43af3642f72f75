"""The glottal gap: detection, opening function and sub-pixel edges."""
