"""Sampling along rays and volume rendering of property channels."""
