"""Load models: surface force fields parameterised by control values."""
