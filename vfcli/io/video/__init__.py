"""High-speed video files: a streaming interface and a reader per format."""
