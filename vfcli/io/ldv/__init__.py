"""Scanning laser-Doppler vibrometer files: readers, writers, grid layout and dropout flags."""
