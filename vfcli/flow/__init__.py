"""The flow stage's science: the glottal gap, optical flow and the tri-variate velocity field."""
