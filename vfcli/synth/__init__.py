"""Phantom recordings: the true motion of the folds with a hidden physics effect, and the instruments that record it."""
