"""Phase-locked synchronisation of sequential LDV epochs onto the video's time base."""
