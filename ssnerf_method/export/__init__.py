"""Exports of a trained model: its renders as a new dataset."""
