"""Edges that touch files: WAV recordings, reference files, truth sidecars."""
