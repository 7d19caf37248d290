"""Evaluation: segmentation metrics and speed (numpy; torch only for checkpoints)."""
